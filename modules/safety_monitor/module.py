"""The flight-safety monitor process: what the robot does, watched against the invariants of issue 31.

The decisions are in :mod:`modules.safety_monitor.logic`; this class feeds it. Inputs: the DSP's ``sent`` stream
(every acknowledged command) and telemetry (slots), the Module Manager's robot state (its task book), the GRI
state and events (the RAL's keys), and in simulation the DSP simulator's truth datagrams on a loopback UDP port
(``--param truth_udp=PORT``; the simulator is started with ``--truth-udp 127.0.0.1:PORT``). Outputs: every breach
on ``breach`` (:class:`bbcs.contracts.safety.Breach`, its code on ``error`` too), what it has watched on ``status``.

One clock: the monitor judges on the robot's clock (``bbcs_clock``: simulated time in a lockstep simulation, where it
is a member the simulation waits for), and every stamp it is given is turned into robot time first
(:mod:`modules.safety_monitor.clocks`: the truth's ``time_s`` from the epoch, the task book's and the DSP process's
wall stamps by the step that was in force then).

It commands nothing and serves no task type: a breach is reported, never acted on.
"""

from __future__ import annotations

import dataclasses
import socket
import threading
import time
from collections.abc import Callable
from typing import Annotated, Any, ClassVar, Literal

import msgspec
import zenoh
import zenoh.ext

from bbcs import (
    InputSlot,
    Kind,
    Module,
    ModuleContext,
    OutputSlot,
    dsp_client,
    load_conf,
    load_params,
    struct_param_errors,
)
from bbcs.clock import SimTime
from bbcs.contracts import dsp as p
from bbcs.contracts import gri, mri
from bbcs.contracts.errors import ErrorReport
from bbcs.contracts.safety import BREACH_SLOT, CODE_OF, STATUS_SLOT, Breach, MonitorStatus
from bbcs.contracts.tasks import TaskInfo
from bbcs.contracts.vehicle_truth import VehicleTruth, decode_truth
from bbcs.lockstep import clock_key
from bbcs.params import ParamError
from modules.safety_monitor.clocks import STAMPED_ON_WALL, RobotTime, truth_behind
from modules.safety_monitor.logic import VEHICLES, MonitorConfig, SafetyMonitor, judged_invariants
from modules.safety_monitor.uquad_truth import UQUAD_TRUTH_PERIOD_S, BadTruthLine, truth_from_bytes

STATUS_PERIOD_S = 1.0
TRUTH_EVERY_S = 0.05
TRUTH_SILENT_S = 2.0
"""Simulated seconds between the truth samples kept (the simulator sends one per physics step)."""


class _Limits(msgspec.Struct, kw_only=True):
    """The robot .conf keys the monitor reads (the RAL's own limits: docs/conf_format.md)."""

    MIN_CLEARANCE: float | None = None
    HOME_LAT: float | None = None
    HOME_LON: float | None = None
    HOME_ALT: float | None = None
    """The uQuad's home (its simulator's origin: its truth is in metres from it)."""
    GEOFENCE: Annotated[list[float], msgspec.Meta(min_length=3, max_length=3)] | None = None


class MonitorParams(msgspec.Struct, frozen=True, kw_only=True):
    """The monitor's manifest ``params`` (``cromat launch --check`` and the module read them the same way);
    unset tolerances keep :class:`MonitorConfig`'s defaults."""

    goal_tolerance_m: Annotated[float, msgspec.Meta(gt=0)] | None = None
    gri_position_m: Annotated[float, msgspec.Meta(gt=0)] | None = None
    abort_latency_s: Annotated[float, msgspec.Meta(gt=0)] | None = None
    loc_attitude_deg: Annotated[float, msgspec.Meta(gt=0, le=180)] | None = None
    truth_udp: Annotated[str, msgspec.Meta(pattern=r"^(((127\.0\.0\.1|localhost)?:)?[0-9]{1,5})?$")] = ""
    """The simulator's truth datagrams: a port (or ``127.0.0.1:PORT``) on this machine; empty: none."""
    vehicle: Literal["uav", "uquad"] = "uav"
    """``uav``: flies through a DSP (its commands and aborts judged); ``uquad``: no DSP (invariants 2, 3 and 5 only,
    :func:`~modules.safety_monitor.logic.judged_invariants`)."""
    truth_tcp: Annotated[str, msgspec.Meta(pattern=r"^(((127\.0\.0\.1|localhost)?:)?[0-9]{1,5})?$")] = ""
    """The uQuad simulator's truth stream (``--truth 127.0.0.1:PORT``, JSON lines) on this machine; empty: none.
    Needs the .conf's HOME_LAT/HOME_LON/HOME_ALT (the simulator's origin)."""


def monitor_param_errors(params: dict[str, str]) -> list[tuple[str, str]]:
    """Every problem of the monitor's manifest ``params``, (key, reason)."""
    return struct_param_errors(MonitorParams, params, what="safety_monitor")


def load_config(context: ModuleContext) -> MonitorConfig:
    """The monitor's configuration from the robot .conf (limits) and its params; ConfError names file and line."""
    params = load_params(MonitorParams, context.params, what="safety_monitor")
    fence = clearance = None
    if context.conf:
        doc = load_conf(context.conf)
        errors = doc.errors_for(_Limits)
        if errors:
            raise errors[0]
        raw = doc.to_struct(_Limits)
        clearance = raw.MIN_CLEARANCE
        fence = (raw.GEOFENCE[0], raw.GEOFENCE[1], raw.GEOFENCE[2]) if raw.GEOFENCE is not None else None
    kw: dict[str, Any] = {name: getattr(params, name) for name in
                          ("goal_tolerance_m", "gri_position_m", "abort_latency_s", "loc_attitude_deg")
                          if getattr(params, name) is not None}
    return MonitorConfig(robot=context.robot, geofence=fence, min_clearance_m=clearance,
                         monitor_name=context.module, **VEHICLES[params.vehicle], **kw)


def truth_port(context: ModuleContext) -> int | None:
    """The truth UDP port on 127.0.0.1, or None; a ``ParamError`` for anything else."""
    raw = load_params(MonitorParams, context.params, what="safety_monitor").truth_udp
    return int(raw.rpartition(":")[2]) if raw else None


def uquad_truth_source(context: ModuleContext) -> tuple[int, tuple[float, float, float]] | None:
    """The uQuad simulator's truth stream port on 127.0.0.1 and its origin (the .conf's HOME_*), or None; a
    ``ParamError`` when the port is given and the .conf has no home."""
    raw = load_params(MonitorParams, context.params, what="safety_monitor").truth_tcp
    if not raw:
        return None
    limits = load_conf(context.conf).to_struct(_Limits) if context.conf else _Limits()
    if limits.HOME_LAT is None or limits.HOME_LON is None or limits.HOME_ALT is None:
        raise ParamError("truth_tcp: the robot .conf has no HOME_LAT, HOME_LON and HOME_ALT (the uQuad simulator's "
                         "origin)")
    return int(raw.rpartition(":")[2]), (limits.HOME_LAT, limits.HOME_LON, limits.HOME_ALT)


class SafetyMonitorModule(Module):
    name: ClassVar[str] = "safety_monitor"
    slots = (
        InputSlot("dsp_sent", p.DspSent, kind=Kind.STREAM, peer=f"{p.MODULE}/{p.SENT_SLOT}", queue=100_000),
        dsp_client.telemetry_input(),
        OutputSlot(BREACH_SLOT, Breach, kind=Kind.STREAM),
        OutputSlot(STATUS_SLOT, MonitorStatus),
        OutputSlot("error", ErrorReport),
    )
    error_slot = "error"
    tick_period = 0.1
    param_errors = staticmethod(monitor_param_errors)
    """The monitor's check of its manifest ``params`` (``cromat launch --check``, with file:line)."""
    params_type = MonitorParams
    runtime_params: frozenset[str] = frozenset()
    """None at run time (``cromat param``): its truth link and limits are set up when it starts."""

    def __init__(self, context: ModuleContext) -> None:
        super().__init__(context)
        self.clock = self.bbcs_clock.time
        """The robot's clock: every judgement and every stamp the monitor compares is on it."""
        self.robot_time = RobotTime(self.clock, simulated=self.sim is not None, known=STAMPED_ON_WALL)
        cfg = load_config(context)
        if self.sim is not None:  # a process's clock moves at a frame's end: its stamps may be a frame early
            cfg = dataclasses.replace(cfg, stamp_lag_s=self.sim.step_s)
        self.monitor = SafetyMonitor(cfg)
        self._truth_port = truth_port(context)
        self._uquad_truth = uquad_truth_source(context)
        self._truth_period = UQUAD_TRUTH_PERIOD_S if self._uquad_truth is not None else 0.0
        """Simulated seconds between two truth samples the simulator sends (0: one at every step's end)."""
        self._truth_sock: socket.socket | None = None
        self._truth_thread: threading.Thread | None = None
        self._watching: list[Any] = []
        self._next_status = 0.0
        self.breaches: list[Breach] = []
        self._truth_read: tuple[float, float] | None = None
        """(time_s, wall monotonic) of the last truth datagram read (lockstep: the step waits for it)."""

    def on_start(self) -> None:
        s = self.session
        assert s is not None
        robot = self.robot
        self._watching += [
            zenoh.ext.declare_advanced_subscriber(
                s, mri.mri_key(robot, mri.STATE), self._decoded(mri.RobotState, self._on_book),
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1)),
            zenoh.ext.declare_advanced_subscriber(
                s, gri.state_key(robot), self._decoded(gri.GriState, self._on_gri_state),
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1)),
            s.declare_subscriber(gri.events_key(robot), self._decoded(gri.GriEvent, self._on_gri_event)),
        ]
        if self.sim is not None:  # when each step reached this process: wall stamps are looked up there
            decode_time = msgspec.msgpack.Decoder(SimTime).decode
            self._watching.append(s.declare_subscriber(
                clock_key(robot), lambda sample: self.robot_time.note_step(decode_time(sample.payload.to_bytes()))))
        if self._truth_port is not None:
            self._truth_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._truth_sock.bind(("127.0.0.1", self._truth_port))
            self._truth_sock.settimeout(0.2)
            self._truth_thread = threading.Thread(target=self._read_truth, name="safety-truth", daemon=True)
            self._truth_thread.start()
        elif self._uquad_truth is not None:
            self._truth_thread = threading.Thread(target=self._read_uquad_truth, name="safety-truth", daemon=True)
            self._truth_thread.start()
        judged = judged_invariants(self.monitor.cfg.dsp_commands,
                                   self._truth_port is not None or self._uquad_truth is not None)
        self.log.info("judging invariants %s", ", ".join(str(int(i)) for i in sorted(judged)))
        self.log.info("watching %s (truth %s)", robot,
                      f"on udp 127.0.0.1:{self._truth_port}" if self._truth_port else
                      f"the uQuad simulator's on tcp 127.0.0.1:{self._uquad_truth[0]}" if self._uquad_truth else
                      "none: not a simulation")

    def on_stop(self) -> None:
        for entity in self._watching:
            entity.undeclare()
        self._watching.clear()
        if self._truth_thread is not None:
            self._truth_thread.join(1.0)
        if self._truth_sock is not None:
            self._truth_sock.close()

    def _decoded(self, typ: type, handler: Callable[[float, Any], None]) -> Callable[[zenoh.Sample], None]:
        decoder = msgspec.msgpack.Decoder(typ)

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                value = decoder.decode(sample.payload.to_bytes())
            except msgspec.MsgspecError as exc:
                self.log.warning("unreadable %s dropped: %s", typ.__name__, exc)
                return
            self.call_soon(lambda: handler(self.clock(), value))

        return on_sample

    def _on_book(self, now: float, state: mri.RobotState) -> None:
        rt = self.robot_time
        rt.learn("manager", state.stamp)

        def on_robot_clock(info: TaskInfo) -> TaskInfo:
            return msgspec.structs.replace(info, started=rt.stamp("manager", info.started),
                                           ended=None if info.ended is None else rt.stamp("manager", info.ended))

        self.monitor.on_book(now, rt.stamp("manager", state.stamp), [on_robot_clock(i) for i in state.tasks],
                             [on_robot_clock(i) for i in state.ended], state.task_epoch)

    def _on_gri_state(self, now: float, state: gri.GriState) -> None:
        rt = self.robot_time
        rt.learn("ral", state.stamp)
        # the RAL stamps its own errors; a module's error is stamped by the Module Manager as it arrives
        errors = [msgspec.structs.replace(e, stamp=rt.stamp("ral" if e.module == "ral" else "manager", e.stamp))
                  for e in state.errors]
        tel = state.telemetry
        if tel is not None:
            rt.learn("telemetry", tel.stamp)
            tel = msgspec.structs.replace(tel, stamp=rt.stamp("telemetry", tel.stamp))
        self.monitor.on_gri_state(now, msgspec.structs.replace(state, stamp=rt.stamp("ral", state.stamp),
                                                               errors=errors, telemetry=tel))

    def _on_gri_event(self, now: float, event: gri.GriEvent) -> None:
        self.monitor.on_gri_event(now, msgspec.structs.replace(event, stamp=self.robot_time.stamp("ral", event.stamp)))

    def _read_truth(self) -> None:
        assert self._truth_sock is not None
        last = -1.0
        while not self.stopping:
            try:
                data = self._truth_sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            try:
                truth = decode_truth(data)
            except msgspec.MsgspecError as exc:
                self.log.warning("bad truth datagram dropped: %s", exc)
                continue
            if truth.time_s - last < TRUTH_EVERY_S and truth.time_s >= last:
                self._truth_read = (truth.time_s, time.monotonic())
                continue
            last = truth.time_s
            self._take_truth(truth)

    def _take_truth(self, truth: VehicleTruth) -> None:
        """One truth sample to the decisions, on the robot's clock (the reading thread)."""
        if self.sim is None:  # the simulator's own time: stamped as it arrives (the wall clock)
            self.call_soon(lambda t=truth: self.monitor.on_truth(self.clock(), t))
            return
        # lockstep: the simulator is the stepper, its time_s is the robot clock's t. Its physics runs ahead of the
        # processes' clocks (they move at the frame's end), so the truth is stamped from its own time
        stamp = self.robot_time.truth(truth.time_s)
        if stamp is not None:
            self.call_soon(lambda t=truth, n=stamp: self.monitor.on_truth(n, t))
        self._truth_read = (truth.time_s, time.monotonic())  # after the hand-over: the loop is busy with it

    def _read_uquad_truth(self) -> None:
        """The uQuad simulator's truth stream (TCP, one JSON line a sample, every 0.05 simulated s): connected again
        whenever it closes (the simulator serves one client at a time). A line cut by a write the simulator could
        not finish is dropped."""
        assert self._uquad_truth is not None
        port, home = self._uquad_truth
        seq = 0
        while not self.stopping:
            try:
                sock = socket.create_connection(("127.0.0.1", port), timeout=1.0)
            except OSError:
                time.sleep(0.2)
                continue
            sock.settimeout(0.2)
            buf = b""
            with sock:
                while not self.stopping:
                    try:
                        data = sock.recv(65536)
                    except TimeoutError:
                        continue
                    except OSError:
                        break
                    if not data:
                        break
                    *lines, buf = (buf + data).split(b"\n")
                    for line in lines:
                        try:
                            truth = truth_from_bytes(line, home, seq)
                        except BadTruthLine as exc:
                            self.log.warning("bad uQuad truth line dropped: %s", exc)
                            continue
                        seq += 1
                        self._take_truth(truth)

    def lockstep_busy(self) -> str:
        """In lockstep the simulator sends the truth of a step before it asks the step, over UDP outside the bus:
        the monitor has handled the step only once it has read the truth up to the step's time (so a verdict or a
        GRI comparison is never made on a truth that is still in its socket). A truth silent for 2 wall seconds is
        not waited for (the simulator sends none, or stopped)."""
        read = self._truth_read
        if read is None or time.monotonic() - read[1] > TRUTH_SILENT_S:
            return ""
        t = self.bbcs_clock.monotonic()
        return f"truth read up to {read[0]:.2f} s of {t:.2f} s" if truth_behind(read[0], t, self._truth_period) \
            else ""

    def on_dsp_sent(self, msg: p.DspSent) -> None:
        self.robot_time.learn("dsp", msg.stamp)
        self.monitor.on_sent(self.clock(), msgspec.structs.replace(msg, stamp=self.robot_time.stamp("dsp", msg.stamp)))

    def on_dsp_telemetry(self, t: p.Telemetry) -> None:
        self.monitor.on_telemetry(self.clock(), t)

    def on_tick(self) -> None:
        now = self.clock()
        for breach in self.monitor.tick(now):
            self.breaches.append(breach)
            self.log.warning("%s", breach.describe())
            self.publish(BREACH_SLOT, breach)
            self.report_error(int(CODE_OF[breach.invariant]), breach.summary)
        if now >= self._next_status:
            self._next_status = now + STATUS_PERIOD_S
            self.publish(STATUS_SLOT, self.status(now))

    def status(self, now: float) -> MonitorStatus:
        m = self.monitor
        return MonitorStatus(robot=self.robot, stamp=now, tasks=len(m.tasks), breaches=dict(m.breach_counts),
                             **m.counts)
