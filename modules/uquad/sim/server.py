"""The simulator's far ends: IMU bytes out, GPS NMEA out, ESC set-points in, a ``truth`` stream (JSON lines:
the true state, for tests and the benchmark) and a ``control`` port (fault injection), each on its own 127.0.0.1
TCP port (one client at a time, a new one replaces the old) or, for the IMU and GPS, a pty.

Control port: one JSON object a line, answered by one line: ``{"motor": 2, "efficiency": 0.0}`` makes motor 2
give no thrust from the next physics step on (``efficiency`` 0…1, 1 repairs it), answered ``{"ok": true, "t":
<simulated time>}``; anything else is answered ``{"ok": false, "error": "<why>"}`` and changes nothing. The
truth lines carry ``motor_efficiency``.

Simulated time runs ``speed`` times faster than the wall clock (1 = real time). Writes never block: bytes a
client does not drain are lost and counted, as on a UART. The ESCs stop the motors when no set-point arrived
for ``esc_timeout_s`` of simulated time (seed: the motors stop when commands stop).

**Lockstep** (``lockstep=True``, PX4 SITL's lockstep on the device links): once the ESC link answers, the
simulator sends an IMU frame and waits for the ESC set-point computed from it before it steps the physics again,
so a starved flight loop slows the flight down instead of changing it; ``speed`` is then the fastest it may go.
Every ``answer_every``-th frame is answered (the flight module's CONTROL_EVERY). A wait longer than
``answer_timeout_s`` (wall) steps on with the last set-point and is counted; ``silent_after`` of them in a row
mean the controller is gone: the simulator runs on the clock again (its ESC timeout stops the motors) until the
ESC link answers again.

**On the bus barrier** (``use_stepper``; the CLI does it when ``CROMAT_SIM`` is in its environment: a lockstep
launch, docs/simulation.md): the simulator is the robot's stepper. It runs ``step_s`` simulated seconds of frames
(each still waiting for its set-point, as above, for up to the launch's ``deadline_s`` of wall time), publishes the
simulated time, asks the barrier, and steps on once every member has handled the step and nothing is still on the
device links (modules/uquad/sim/lockstep.py); ``speed`` then paces whole steps (None: as fast as answered). The
truth lines then also carry ``stamp``, the sample's simulated time as the robot's clocks read it (epoch + t).
"""

from __future__ import annotations

import json
import os
import select
import socket
import time
import tty
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from modules.uquad import motor_protocol as mp
from modules.uquad.gps import encode as encode_nmea
from modules.uquad.imu_protocol import encode_ascii, encode_binary
from modules.uquad.sim.lockstep import DeviceLinks, LinkCheck, frames_per_step, next_step_at
from modules.uquad.sim.quad import QuadSim

if TYPE_CHECKING:
    from bbcs.lockstep import Done, Stepper

MOTORS = 4


def parse_control(line: bytes) -> tuple[int, float]:
    """A control-port line → (motor, efficiency); ValueError saying why it is refused."""
    try:
        doc = json.loads(line)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"not JSON: {exc}") from None
    if not isinstance(doc, dict) or set(doc) != {"motor", "efficiency"}:
        raise ValueError('expected {"motor": 0-3, "efficiency": 0-1}')
    motor, eff = doc["motor"], doc["efficiency"]
    if isinstance(motor, bool) or not isinstance(motor, int) or not 0 <= motor < MOTORS:
        raise ValueError(f"motor must be an integer 0..{MOTORS - 1}, not {motor!r}")
    if isinstance(eff, bool) or not isinstance(eff, int | float) or not 0.0 <= eff <= 1.0:
        raise ValueError(f"efficiency must be a number in [0, 1], not {eff!r}")
    return motor, float(eff)

PHYSICS_DT = 0.002
IMU_PERIOD = 0.010


class TcpEnd:
    """A listening socket that serves its latest client."""

    def __init__(self, name: str, host: str, port: int) -> None:
        self.name = name
        self.listener = socket.create_server((host, port))
        self.listener.setblocking(False)
        self.client: socket.socket | None = None
        self.connections = 0
        """Clients accepted so far (lockstep counts each link per connection)."""
        self.tx = 0
        """Bytes written to the current client."""
        host, port = self.listener.getsockname()[:2]
        self.url = f"tcp://{host}:{port}"

    @property
    def connected(self) -> bool:
        return self.client is not None

    def fds(self) -> list[int]:
        return [self.listener.fileno()] + ([self.client.fileno()] if self.client else [])

    def readable(self, fd: int) -> bytes:
        if fd == self.listener.fileno():
            conn, _ = self.listener.accept()
            conn.setblocking(False)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            if self.client is not None:
                self.client.close()
            self.client = conn
            self.connections += 1
            self.tx = 0
            return b""
        assert self.client is not None
        try:
            data = self.client.recv(65536)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            data = b""
        if not data:
            self.client.close()
            self.client = None
        return data

    def write(self, data: bytes) -> int:
        if self.client is None:
            return 0
        try:
            sent = self.client.send(data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError:
            self.client.close()
            self.client = None
            return 0
        self.tx += sent
        return sent

    def close(self) -> None:
        if self.client:
            self.client.close()
        self.listener.close()


class PtyEnd:
    """A pty pair; the robot opens ``path`` like a serial port."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self.master, False)
        self.url = os.ttyname(self._slave)
        self.connected = True  # a pty is always "connected": unread bytes wait in its buffer
        self.connections = 1
        self.tx = 0

    def fds(self) -> list[int]:
        return [self.master]

    def readable(self, fd: int) -> bytes:
        try:
            return os.read(self.master, 65536)
        except OSError:
            return b""

    def write(self, data: bytes) -> int:
        try:
            sent = os.write(self.master, data)
        except OSError:
            return 0
        self.tx += sent
        return sent

    def close(self) -> None:
        os.close(self.master)
        os.close(self._slave)


@dataclass
class SimStats:
    imu_frames: int = 0
    """Frames written while a client was connected."""
    imu_bytes_lost: int = 0
    gps_fixes: int = 0
    esc_frames: int = 0
    esc_bad: int = 0
    esc_timeouts: int = 0
    lockstep_waits: int = 0
    """IMU frames after which the simulator waited for the ESC set-point."""
    lockstep_timeouts: int = 0
    """Waits that ended without one (the physics stepped on with the last set-point)."""
    last_esc: list[float] = field(default_factory=lambda: [0.0] * 4)


class SimServer:
    def __init__(self, sim: QuadSim, imu: TcpEnd | PtyEnd, gps: TcpEnd | PtyEnd | None, esc: TcpEnd,
                 truth: TcpEnd | None, *, imu_mode: str = "binary", speed: float = 1.0, gps_period: float = 0.2,
                 esc_timeout_s: float = 0.1, truth_period: float = 0.05, control: TcpEnd | None = None,
                 lockstep: bool = False, answer_every: int = 1, answer_timeout_s: float = 0.5,
                 silent_after: int = 5) -> None:
        self.sim, self.imu, self.gps, self.esc, self.truth = sim, imu, gps, esc, truth
        self.control = control
        self._control_buf = b""
        self.encode = encode_binary if imu_mode == "binary" else encode_ascii
        self.speed = speed
        self.gps_period = gps_period
        self.esc_timeout_s = esc_timeout_s
        self.truth_period = truth_period
        self.stats = SimStats()
        self.esc_parser = mp.FrameParser("E")
        self._last_esc_t = -1e9
        self._stop = False
        self.lockstep = lockstep
        self.answer_every = answer_every
        self.answer_timeout_s = answer_timeout_s
        self.silent_after = silent_after
        self._answering = False
        """Lockstep: the ESC link has answered since it connected and has not gone silent."""
        self._misses = 0
        self._next_imu = IMU_PERIOD
        self._next_gps = gps_period
        self._next_truth = 0.0
        self._frames = 0
        self.stepper: Stepper | None = None
        """On the bus barrier (``use_stepper``), or None: on the clock / the device links only."""
        self.step_s = 0.2
        self.step_speed: float | None = None
        self._link_check = LinkCheck()
        self._esc_rx = 0
        self._esc_rx_connection = 0
        self.wall_s = 0.0
        """Wall seconds ``run`` took (the lockstep summary)."""

    def use_stepper(self, stepper: Stepper, step_s: float, speed: float | None, deadline_s: float) -> None:
        """Step on this bus barrier (before ``run``): ``step_s`` of frames a step, at most ``speed`` times real time
        (None: as fast as answered), each frame's set-point waited for up to ``deadline_s`` wall seconds (the
        barrier's own patience with a slow member). The device links' lockstep is on."""
        self.stepper = stepper
        self.step_s = step_s
        self.step_speed = speed
        self.lockstep = True
        self.answer_timeout_s = deadline_s
        stepper.use_check(self._links_settled)

    def links(self) -> DeviceLinks:
        """The device links' counters as the barrier's check reads them."""
        esc = self.esc
        return DeviceLinks(imu_tx=self.imu.tx, imu_readers=self.imu.connections,
                           gps_tx=self.gps.tx if self.gps is not None else 0,
                           esc_rx=self._esc_rx if self._esc_rx_connection == esc.connections else 0,
                           esc_connection=esc.connections, esc_connected=esc.connected)

    def _links_settled(self, answers: dict[str, Done]) -> str:
        return self._link_check(answers, self.links())

    def stop(self) -> None:
        self._stop = True

    def ends(self) -> list[TcpEnd | PtyEnd]:
        return [e for e in (self.imu, self.gps, self.esc, self.truth, self.control) if e is not None]

    def _poll(self, timeout: float) -> None:
        owners: dict[int, TcpEnd | PtyEnd | None] = {fd: end for end in self.ends() for fd in end.fds()}
        if self.stepper is not None:
            owners[self.stepper.wake_fd] = None
        ready, _, _ = select.select(list(owners), [], [], max(0.0, timeout))
        for fd in ready:
            end = owners[fd]
            if end is None:  # the barrier's answers: read by the stepper's poll
                assert self.stepper is not None
                self.stepper.drain_wake()
                continue
            data = end.readable(fd)
            if end is self.esc and not self.esc.connected:
                self._answering = False  # a new driver link must answer before the simulator waits on it
            if end is self.esc and data:
                self._answering = self.lockstep
                if self._esc_rx_connection != self.esc.connections:
                    self._esc_rx_connection, self._esc_rx = self.esc.connections, 0
                for frame in self.esc_parser.feed(data):
                    self._esc_rx += 1
                    self.stats.esc_frames += 1
                    self.stats.last_esc = list(mp.speeds(frame))
                    self.sim.command(self.stats.last_esc)
                    self._last_esc_t = self.sim.t
                self.stats.esc_bad = self.esc_parser.bad_frames
            elif end is self.control and data:
                self._on_control(data)

    def _on_control(self, data: bytes) -> None:
        """Fault injection: each complete line is applied (or refused) and answered."""
        assert self.control is not None
        self._control_buf = (self._control_buf + data)[-65536:]
        *lines, self._control_buf = self._control_buf.split(b"\n")
        for line in lines:
            if not line.strip():
                continue
            try:
                motor, eff = parse_control(line)
            except ValueError as exc:
                answer = {"ok": False, "error": str(exc)}
            else:
                self.sim.fail_motor(motor, eff)
                answer = {"ok": True, "t": round(self.sim.t, 4)}
                print(f"uquad sim: motor {motor} efficiency {eff:g} at t={self.sim.t:.3f}", flush=True)
            self.control.write((json.dumps(answer) + "\n").encode())

    def _truth_line(self) -> bytes:
        s = self.sim
        doc = {"t": round(s.t, 4), **({"stamp": round(self.stepper.epoch + s.t, 4)} if self.stepper else {}),
               "x": [round(float(v), 5) for v in s.x], "w": [round(float(v), 2) for v in s.w],
               "on_ground": s.on_ground, "imu_frames": self.stats.imu_frames, "esc_frames": self.stats.esc_frames,
               "esc_timeouts": self.stats.esc_timeouts, "imu_bytes_lost": self.stats.imu_bytes_lost,
               "esc": [round(float(v), 2) for v in self.stats.last_esc],
               "motor_efficiency": [round(float(v), 3) for v in s.motor_efficiency]}
        return (json.dumps(doc) + "\n").encode()

    def _await_answer(self, esc_frames_before: int) -> None:
        """Lockstep: poll until the ESC set-point answering the frame just sent arrives, or the wait times out."""
        self.stats.lockstep_waits += 1
        deadline = time.monotonic() + self.answer_timeout_s
        while self.stats.esc_frames == esc_frames_before and self._answering and not self._stop:
            if self.stepper is not None and not self.imu.connected:
                return  # on the barrier: the flight module gone (its IMU link closed), nobody will answer
            left = deadline - time.monotonic()
            if left <= 0:
                self.stats.lockstep_timeouts += 1
                self._misses += 1
                if self._misses >= self.silent_after:
                    self._answering = False
                    print(f"uquad sim: no ESC answer to {self._misses} frames: on the clock again at "
                          f"t={self.sim.t:.2f}", flush=True)
                return
            self._poll(min(left, 0.5))  # a stop (a signal) is seen within 0.5 s however long the wait
        self._misses = 0

    def run(self, duration_s: float | None = None) -> None:
        """Serve until ``stop()`` (or ``duration_s`` of simulated time)."""
        started = time.monotonic()
        try:
            if self.stepper is not None:
                self._run_stepped(self.stepper, duration_s)
                return
            sim = self.sim
            period = IMU_PERIOD / self.speed
            next_wall = time.monotonic() + period
            while not self._stop and (duration_s is None or sim.t < duration_s):
                self._poll(next_wall - time.monotonic())
                now = time.monotonic()
                if now < next_wall:
                    continue
                # on the clock, late frames catch up; in lockstep a slow step delays the ones after it
                next_wall = max(next_wall + period, now) if self._answering else next_wall + period
                self._frame(self._next_imu)
                self._next_imu += IMU_PERIOD
        finally:
            self.wall_s = time.monotonic() - started

    def _run_stepped(self, stepper: Stepper, duration_s: float | None) -> None:
        """On the bus barrier: ``step_s`` of frames, then the barrier; nothing moves before it is settled."""
        sim = self.sim
        per_step = frames_per_step(self.step_s)
        step = per_step * IMU_PERIOD  # whole frames: the flight loop's frame count stays simulated time
        step_wall = None if self.step_speed is None else step / self.step_speed
        settled = False
        next_wall = time.monotonic()
        start = sim.t
        stepper.begin(start)  # step 0: nothing moves before the whole robot is up and has answered
        while not self._stop and (duration_s is None or sim.t < duration_s):
            if not settled:
                self._poll(stepper.timeout())
                settled = stepper.poll()
                continue
            now = time.monotonic()
            if step_wall is not None and now < next_wall:
                self._poll(next_wall - now)  # paced: commands and faults still read meanwhile
                continue
            # the step ends at start + step as a member computing a period (``now + period``) adds it: summed frame
            # by frame it may end an ulp short of that, and a robot state due every step would wait for the next
            end = start + step
            for i in range(1, per_step + 1):
                if self._stop:
                    break
                self._frame(end if i == per_step else start + i * IMU_PERIOD)
            next_wall = next_step_at(next_wall, now, step_wall)
            start = end
            stepper.begin(sim.t)
            settled = False

    def _frame(self, at: float) -> None:
        """One IMU period: the physics to the frame's time ``at``, the ESCs' timeout, GPS and truth when due, then the
        IMU frame and (device lockstep, once the ESC link answers) the wait for the set-point computed from it."""
        sim = self.sim
        while sim.t + PHYSICS_DT / 2 < at:
            sim.step(PHYSICS_DT)
            sim.t += PHYSICS_DT
        sim.t = at
        if sim.t - self._last_esc_t > self.esc_timeout_s and np.any(sim.w_cmd):
            sim.command([0.0] * 4)  # commands stopped: the ESCs stop the motors
            self.stats.esc_timeouts += 1
        if self.gps is not None and sim.t >= self._next_gps:  # before the IMU frame: read first, in lockstep too
            self._next_gps += self.gps_period
            if self.gps.write(encode_nmea(sim.gps_fix(), 43_200.0 + sim.t)):
                self.stats.gps_fixes += 1
        if self.truth is not None and sim.t >= self._next_truth:
            self._next_truth += self.truth_period
            self.truth.write(self._truth_line())
        frame = self.encode(sim.imu_frame())
        esc_before = self.stats.esc_frames
        if self.imu.connected:
            sent = self.imu.write(frame)
            self.stats.imu_frames += 1
            self.stats.imu_bytes_lost += len(frame) - sent
            self._frames += 1
            if self._answering and self._frames % self.answer_every == 0:
                self._await_answer(esc_before)

    def close(self) -> None:
        for end in self.ends():
            end.close()
