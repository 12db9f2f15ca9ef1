"""The simulated DSP on a real transport: bytes in → frames → DspMachine → ACKs, telemetry and errors out.

The loop is one thread around ``select``: it reads the line, answers commands at once, and steps the flight
at a fixed rate (``rate_hz`` of simulated time, run ``time_scale`` times faster than the wall clock), or, in a
lockstep simulation (``stepper``, docs/simulation.md), one frame of ``frame_s`` simulated seconds at a time, each
only once every module has handled the last one and the DSP line carried every byte both ways. Every
command received is recorded in order with its time — in memory (``commands``) and, if asked, as JSON lines
in a file — so tests can check exactly what the PC sent.
"""

from __future__ import annotations

import json
import logging
import os
import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import IO, TYPE_CHECKING

import msgspec
import numpy as np

from bbcs.contracts import dsp as p
from bbcs.lockstep import frames_due, wire_counts, wire_end
from modules.dsp.codec import PC_TO_DSP_LENGTHS, encode, message_name
from modules.dsp.codec import _encode_telemetry as encode_telemetry_unchecked
from modules.dsp.framing import FrameParser, build_frame
from modules.dsp.link import lockstep_link
from modules.dsp.sim.faults import BadTelemetry, FaultInjector, garble
from modules.dsp.sim.machine import DspMachine, DspParams
from modules.dsp.sim.transport import Endpoint
from modules.dsp.sim.truth import TruthSender
from modules.dsp.sim.vehicle import VehicleParams

if TYPE_CHECKING:
    from bbcs.lockstep import Done, Follower, Stepper

log = logging.getLogger(__name__)
MAX_CATCH_UP_STEPS = 50
"""Steps behind the wall clock beyond which simulated time slips instead of catching up."""
STEPS_PER_PASS = 5
"""Steps between two looks at the line while catching up."""
FOLLOWER_JUMP_FRAMES = 100
"""A fleet follower further behind the fleet's time than this many physics steps joined late (its robot launched
or relaunched into a running fleet): its time jumps to the fleet's instead of flying the gap on the ground."""


@dataclass(frozen=True)
class RecordedCommand:
    """One command frame as the DSP received it."""

    t_sim: float  # DSP time, s
    t_wall: float  # s since the simulator started
    seq: int
    msg_id: int
    name: str
    fields: dict
    status: int
    duplicate: bool
    t_mono: float = 0.0  # the host's CLOCK_MONOTONIC at reception: comparable across processes (latency benches)

    def as_json(self) -> str:
        return json.dumps({"t": round(self.t_sim, 6), "wall": round(self.t_wall, 6), "mono": round(self.t_mono, 6),
                           "seq": self.seq,
                           "id": self.msg_id, "name": self.name, "fields": self.fields, "status": self.status,
                           "status_name": p.dsp_error_name(self.status), "duplicate": self.duplicate})


@dataclass(frozen=True)
class SimSnapshot:
    """A consistent copy of the simulated DSP's state."""

    time_s: float
    mode: int
    tracking: bool
    path_valid: bool
    queue_length: int
    waypoints_reached: int
    speed_cmd: float
    heading: float
    lat: float
    lon: float
    alt: float
    local: tuple[float, float, float]
    airborne: bool
    error_code: int
    heli_type: int | None
    pid_axes: tuple[int, ...]
    pt_mode: int
    pan: float
    tilt: float
    state_tx: bool
    telemetry_mask: int


class DspSimulator:
    """A DSP on ``endpoint``. Use ``start()``/``stop()`` (a thread, for tests) or ``run()`` (the CLI)."""

    def __init__(self, endpoint: Endpoint, *, params: DspParams | None = None,
                 vehicle_params: VehicleParams | None = None, rate_hz: float = 50.0, time_scale: float = 1.0,
                 baud: int = 921_600, tx_faults: FaultInjector | None = None,
                 rx_faults: FaultInjector | None = None, record_path: str | os.PathLike[str] | None = None,
                 fail_at: list[tuple[float, int]] | None = None, seed: int | None = None,
                 bad_telemetry: BadTelemetry | None = None, clock: Callable[[], float] = time.monotonic,
                 truth: TruthSender | None = None, stepper: Stepper | None = None, frame_s: float = 0.2,
                 speed: float | None = 1.0) -> None:
        if rate_hz <= 0 or time_scale <= 0:
            raise ValueError("rate_hz and time_scale must be positive")
        self.endpoint = endpoint
        self.machine = DspMachine(params, vehicle_params)
        self.machine.scheduled_errors = sorted(fail_at or [])
        self.rate_hz = rate_hz
        self.time_scale = time_scale
        self.baud = baud
        self.tx_faults = tx_faults
        self.rx_faults = rx_faults
        self.bad_telemetry = bad_telemetry
        self.truth = truth  # the aircraft's true state to the lidar simulators (modules/dsp/sim/truth.py)
        self.stepper = stepper
        """Lockstep: the barrier each frame waits on (bbcs/lockstep.py); None: free-running on ``clock``."""
        self.frame_s = frame_s
        self.speed = speed
        """Lockstep: simulated seconds per wall second at most (None: as fast as the modules allow)."""
        self.line_rx = 0
        self.line_tx = 0
        """Bytes read from / written to the PC now on the line (since it connected): lockstep compares them."""
        self._line_client = 0
        self.follower: Follower | None = None
        """A fleet's follower (``use_follower``): steps when another robot's simulator says (bbcs/lockstep.py)."""
        if stepper is not None:
            self.use_stepper(stepper)
        self._clock = clock
        self._rng = np.random.default_rng(seed)
        self._parser = FrameParser(PC_TO_DSP_LENGTHS)
        self._lock = threading.Lock()
        self._commands: list[RecordedCommand] = []
        self._record: IO[str] | None = open(record_path, "a", encoding="utf-8") if record_path else None  # noqa: SIM115
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        self._thread: threading.Thread | None = None
        self._tx_seq = 0
        self._start_wall = clock()
        self._closed = False
        self._running = False
        self.line_baud: int | None = None
        self.tx_frames = 0
        self.tx_bytes_lost = 0
        self.error: BaseException | None = None

    # --- control -----------------------------------------------------------------------------------------

    def start(self) -> DspSimulator:
        self._thread = threading.Thread(target=self._run_safely, name="dsp-sim", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the loop (from any thread or a signal handler), then release the transport; idempotent."""
        self._stop.set()
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
            self._close()
        elif self._thread is None and not self._running:
            self._close()  # never started: release the line and the record file now

    def _run_safely(self) -> None:
        try:
            self.run()
        except BaseException as exc:  # surfaced to tests through .error
            self.error = exc
            log.exception("DSP simulator stopped")

    def _close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self.endpoint.close()
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass
        if self._record is not None:
            self._record.close()
        if self.truth is not None:
            self.truth.close()

    def use_follower(self, follower: Follower) -> None:
        """Step on a fleet's barrier, led by another robot's simulator (before ``run``): the physics moves to each
        step's time when its first ask arrives; the DSP line is paired with the DSP module's by the barrier."""
        self.follower = follower

    def use_stepper(self, stepper: Stepper) -> None:
        """Step on this lockstep barrier (before ``run``): frames of ``frame_s``, the DSP line checked."""
        self.stepper = stepper
        stepper.use_check(self._line_settled)

    # --- observation ---------------------------------------------------------------------------------------

    @property
    def commands(self) -> list[RecordedCommand]:
        with self._lock:
            return list(self._commands)

    @property
    def rx_stats(self) -> dict[str, int]:
        with self._lock:
            return self._parser.stats.as_dict()

    def snapshot(self) -> SimSnapshot:
        with self._lock:
            m = self.machine
            st = m.vehicle.state
            lat, lon, alt = m.to_global(st.pos)
            return SimSnapshot(
                time_s=m.time_s, mode=int(m.mode), tracking=m.tracking, path_valid=m.path_valid,
                queue_length=len(m.queue), waypoints_reached=m.waypoints_reached, speed_cmd=m.speed_cmd,
                heading=st.heading, lat=float(lat), lon=float(lon), alt=float(alt),
                local=(float(st.pos[0]), float(st.pos[1]), float(st.pos[2])), airborne=st.airborne,
                error_code=m.error_code, heli_type=None if m.heli_type is None else int(m.heli_type),
                pid_axes=tuple(sorted(int(a) for a in m.pids)), pt_mode=int(m.pt_mode), pan=m.pan,
                tilt=m.tilt,
                state_tx=m.state_tx, telemetry_mask=m.telemetry_mask)

    # --- the loop ----------------------------------------------------------------------------------------

    def run(self) -> None:
        if self.stepper is not None:
            self._run_lockstep(self.stepper)
            return
        if self.follower is not None:
            self._run_following(self.follower)
            return
        dt = 1.0 / self.rate_hz
        wall_dt = dt / self.time_scale
        next_tick = self._clock()
        next_baud_check = 0.0
        self._running = True
        try:
            while not self._stop.is_set():
                timeout = max(0.0, next_tick - self._clock())
                ready, _, _ = select.select([*self.endpoint.fileno_list(), self._wake_r], [], [], timeout)
                for fd in ready:
                    if fd == self._wake_r:
                        os.read(self._wake_r, 64)
                        continue
                    data = self.endpoint.on_readable(fd)
                    if data:
                        self._on_rx(data)
                now = self._clock()
                if now >= next_baud_check:
                    self._check_baud()
                    next_baud_check = now + 0.1
                steps = 0
                # a few steps per pass, then back to select: a simulator catching up (a loaded machine) still
                # answers every command within a few steps, as the real DSP's interrupt-driven line does
                while now >= next_tick and steps < STEPS_PER_PASS:
                    self._physics_step(dt)
                    next_tick += wall_dt
                    steps += 1
                if now - next_tick > MAX_CATCH_UP_STEPS * wall_dt:
                    next_tick = now + wall_dt  # could not keep up: let simulated time slip instead of spiralling
        finally:
            self._running = False
            if self._thread is None:
                self._close()

    def _run_lockstep(self, stepper: Stepper) -> None:
        """Frames of ``frame_s`` simulated seconds: the physics sub-steps at ``rate_hz``, then the barrier.

        Commands are read and acknowledged at once while the barrier waits (the DSP module's sender must get its
        ACKs for the step to settle); simulated time stands still until every member has answered."""
        dt = 1.0 / self.rate_hz
        steps = max(1, round(self.frame_s / dt))
        frame_wall = None if self.speed is None else steps * dt / self.speed
        fds = [self._wake_r, stepper.wake_fd]
        self._running = True
        settled = False
        next_wall = self._clock()
        stepper.begin(self.machine.time_s)  # frame 0: nothing moves before the whole robot is up and has answered
        try:
            while not self._stop.is_set():
                now = self._clock()
                due = settled and (frame_wall is None or now >= next_wall)
                timeout = 0.0 if due else (max(0.0, next_wall - now) if settled else stepper.timeout())
                ready, _, _ = select.select([*self.endpoint.fileno_list(), *fds], [], [], timeout)
                for fd in ready:
                    if fd == self._wake_r:
                        os.read(self._wake_r, 64)
                    elif fd == stepper.wake_fd:
                        stepper.drain_wake()
                    else:
                        data = self.endpoint.on_readable(fd)
                        if data:
                            self._on_rx(data)
                if not settled:
                    settled = stepper.poll()
                    continue
                started = self._clock()
                if frame_wall is not None and started < next_wall:
                    continue
                for _ in range(steps):
                    self._physics_step(dt)
                if frame_wall is not None:  # paced from when this frame started: a late frame is not made up
                    next_wall = max(next_wall, started) + frame_wall
                stepper.begin(self.machine.time_s)
                settled = False
        finally:
            self._running = False
            wall = self._clock() - self._start_wall
            log.info("lockstep: %d frames, %d rounds, %.1f s simulated in %.1f s of wall (%.2fx)", stepper.step,
                     stepper.rounds, self.machine.time_s, wall, self.machine.time_s / wall if wall > 0 else 0.0)
            if self._thread is None:
                self._close()

    def _run_following(self, follower: Follower) -> None:
        """A fleet's follower: each new step's first ask moves the physics to its time (sub-steps at ``rate_hz``,
        what they produce written to the line); every ask is answered with the frames and commands handled so
        far and the line's byte counts, which the barrier pairs with the DSP module's (``wire_counts``).
        Commands are read and acknowledged at once, as in ``_run_lockstep``."""
        dt = 1.0 / self.rate_hz
        link = lockstep_link(follower.robot)
        fds = [self._wake_r, follower.wake_fd]
        self._running = True
        handled = 0
        try:
            while not self._stop.is_set():
                ready, _, _ = select.select([*self.endpoint.fileno_list(), *fds], [], [], 0.5)
                ask = None
                for fd in ready:
                    if fd == self._wake_r:
                        os.read(self._wake_r, 64)
                    elif fd == follower.wake_fd:
                        ask = follower.take()
                    else:
                        data = self.endpoint.on_readable(fd)
                        if data:
                            self._on_rx(data)
                            handled += 1
                if ask is None:
                    continue
                due = frames_due(ask.now.t, self.machine.time_s, dt)
                if due > FOLLOWER_JUMP_FRAMES:  # joined a fleet long under way: on the ground until now
                    log.warning("lockstep: joining the fleet at %.1f s simulated: the aircraft waited until then",
                                ask.now.t)
                    with self._lock:
                        self.machine.time_s = ask.now.t
                    due = 0
                for _ in range(due):
                    self._physics_step(dt)
                handled += due
                self._follow_client()
                follower.answer(ask, handled, wire_counts(link, self.line_tx, self.line_rx))
        finally:
            self._running = False
            log.info("lockstep (following): %.1f s simulated in %.1f s of wall", self.machine.time_s,
                     self._clock() - self._start_wall)
            if self._thread is None:
                self._close()

    def _physics_step(self, dt: float) -> None:
        """One physics step: the truth to the lidar simulators, then what the DSP sends written to the line."""
        with self._lock:
            out = self.machine.step(dt)
            if self.truth is not None:
                self.truth.send(self.machine)
        for msg in out:
            self._send(msg)

    def _line_settled(self, answers: dict[str, Done]) -> str:
        """Lockstep: '' once the DSP module has read every byte sent to it and the simulator every byte it wrote
        (nothing still on the line); else what is missing."""
        self._follow_client()
        link = lockstep_link(self.stepper.robot) if self.stepper is not None else ""
        for done in answers.values():
            end = wire_end(done.counts, link)
            if end is None:
                continue
            tx, rx = end
            with self._lock:
                line_rx, line_tx = self.line_rx, self.line_tx
            if tx != line_rx or rx != line_tx:
                return f"DSP line: {done.member} wrote {tx} B (read here {line_rx}), read {rx} B (sent {line_tx})"
        return ""

    def _follow_client(self) -> None:
        client = getattr(self.endpoint, "connections", 0)
        if client != self._line_client:  # a new PC on the line (the DSP module restarted): count from zero
            with self._lock:
                self._line_client = client
                self.line_rx = self.line_tx = 0

    def _check_baud(self) -> None:
        baud = self.endpoint.line_baud()
        if baud != self.line_baud:
            if baud is not None and baud != self.baud:
                log.warning("line set to %d baud, the DSP runs at %d: both directions will be garbage",
                            baud, self.baud)
            self.line_baud = baud

    @property
    def baud_mismatch(self) -> bool:
        return self.line_baud is not None and self.line_baud != self.baud

    def _on_rx(self, data: bytes) -> None:
        self._follow_client()
        self.line_rx += len(data)
        self._check_baud()  # the PC sets its speed before it writes: never decode bytes sent at a wrong rate
        if self.baud_mismatch:
            data = garble(data, self._rng, self.baud / self.line_baud)  # type: ignore[operator]
        if self.rx_faults is not None:
            data = self.rx_faults.apply(data)
        acks = []
        with self._lock:
            stats = self._parser.stats
            before = stats.bytes_discarded
            frames = self._parser.feed(data)
            now = self._clock()
            for frame in frames:
                result = self.machine.handle(frame, now)
                fields = {} if result.command is None else msgspec.to_builtins(result.command)
                rec = RecordedCommand(t_sim=self.machine.time_s, t_wall=now - self._start_wall, seq=frame.seq,
                                      msg_id=frame.msg_id, name=message_name(frame.msg_id), fields=fields,
                                      status=result.ack.status, duplicate=result.duplicate, t_mono=now)
                self._commands.append(rec)
                if self._record is not None:
                    self._record.write(rec.as_json() + "\n")
                    self._record.flush()
                acks.append(result.ack)
            if stats.bytes_discarded > before:
                self.machine.note_rx_errors()
        for ack in acks:
            self._send(ack)

    def _send(self, msg: p.Message) -> None:
        bad = self.bad_telemetry.spoil(msg) if self.bad_telemetry and isinstance(msg, p.Telemetry) else None
        if bad is not None:  # out of range with a good CRC: encode() would refuse it, so frame it by hand
            frame = build_frame(int(p.MsgId.TELEMETRY), self._tx_seq, encode_telemetry_unchecked(bad))
        else:
            frame = encode(msg, self._tx_seq)
        self._tx_seq = (self._tx_seq + 1) & 0xFF
        if self.baud_mismatch:
            frame = garble(frame, self._rng, self.line_baud / self.baud)  # type: ignore[operator]
        if self.tx_faults is not None:
            frame = self.tx_faults.apply(frame)
        self._follow_client()
        written = self.endpoint.write(frame)
        self.line_tx += written
        self.tx_frames += 1
        self.tx_bytes_lost += len(frame) - written
