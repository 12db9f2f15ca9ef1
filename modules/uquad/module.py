"""The uQuad's main process (the seed's ``main``) as a bus module: ``python -m modules.uquad``.

One flight thread runs the seed's loop with ``select()``: read every IMU byte available (never fall behind the
IMU), GPS when there is some, then the FlightCore (calibration, Kalman, planner, controller) and the motor
command to the driver process, whose acks it checks. Bus handlers only queue the task mode and the waypoints
for the flight thread, so the bus never delays the control loop; the loop publishes the generic
RobotTelemetry (10 Hz) and its data slots (raw IMU frames, state, control actions) for the logging processes.

Inputs (routed by CONTROL_ENTRADA): ``modo`` (UquadMode, the manager's mode slot for the running task),
``path`` (the RAL's waypoint slot) and ``task`` (the RAL's task slot: the started task's parameters, so the
take-off height, the goto speed and the manual steps the ground station asked for reach the planner).
Params: ``imu`` (tcp://host:port, a serial device, or file://raw-log for
the seed's fake mode), ``gps`` (tcp://…, a device; GPS_MODE in the .conf decides real/fake/none), ``motor``
(tcp://… of the driver, or ``sim``: actuators simulated, commands only published), ``controller`` (hover |
setpoint), ``clock`` (wall: Ts from elapsed wall time, as the seed; imu: 10 ms per frame, for replay and
faster-than-real-time simulation), ``record_raw`` (a file: every IMU byte read is appended, a raw log for the
fake mode), ``nice`` (default 0: the process's scheduling niceness, every thread; negative needs the right to
raise priority, as a flight computer's loop has; refused → a warning and the default).

In a lockstep simulation (``CROMAT_SIM``, docs/uquad.md §1.1) the flight loop times itself by the simulator's
frames whatever ``clock`` says, stamps its data and telemetry with simulated time, judges the driver's ack
timeout on it, and answers the barrier with what its threads have handled (modules/uquad/lockstep.py).
"""

from __future__ import annotations

import gc
import os
import queue
import select
import sys
import threading
import time
from typing import Any, ClassVar

import numpy as np

from bbcs import ConfError, Control, InputSlot, Kind, Module, OutputSlot, Safety
from bbcs.contracts.error_codes import UquadErrorCode
from bbcs.contracts.errors import ErrorReport
from bbcs.contracts.mri import MODE_ACK_SLOT, ModeAck, mode_echo
from bbcs.contracts.path_follower import DatosSegCam  # the RAL's path slot type
from bbcs.contracts.robot import Attitude, GeoPoint, RobotTelemetry, VelocityNED
from bbcs.contracts.tasks import TaskData
from modules.uquad import model
from modules.uquad.calibration import load_calibration
from modules.uquad.config import conf_errors, load_config
from modules.uquad.core import FlightCore
from modules.uquad.geo import Home
from modules.uquad.gps import FakeGps, LocalGps, NmeaReader
from modules.uquad.imu_protocol import ImuParser
from modules.uquad.lockstep import FRAME_S, FlightLedger, crossed, flight_time, sim_epoch
from modules.uquad.motor_client import MotorClient
from modules.uquad.params import load_uquad_params, uquad_param_errors
from modules.uquad.planner import Mode, apply_task, heading_deg
from modules.uquad.structs import ControlEntradaUquad, ImuRaw, MotorCommandLog, UquadMode, UquadState
from modules.uquad.transport import Stream, read_available

TELEMETRY_PERIOD_S = 0.1
TELEMETRY_EVERY = round(TELEMETRY_PERIOD_S / FRAME_S)
"""Lockstep: the telemetry period in IMU frames (simulated time)."""
TELEMETRY_PHASE = TELEMETRY_EVERY // 2
"""Lockstep: the telemetry goes out half a period off the simulator's steps (frames 5, 15, ...): the last one of a
step has reached the manager when the step ends and the robot state due then carries it (published at the step's
end, it would race the state, which would carry it or the one before)."""
STATE_EVERY = 2  # state published every this many IMU frames (50 Hz)
SWITCH_INTERVAL_S = 0.0005
"""The interpreter's thread switch interval in this process (default 5 ms): the flight thread, woken by the
IMU, gets the interpreter from the bus threads within this, not within 5 ms (the seed's budget is 10 ms)."""
OUTBOX_SIZE = 2000
"""Data waiting for the bus writer thread; when full (a logger or the bus is slower than the IMU), the newest
datum is dropped and counted: the control loop never waits for the bus (seed 002 §1.2.1)."""


class UquadModule(Module):
    name: ClassVar[str] = "uquad"
    slots = (
        InputSlot("modo", UquadMode),
        InputSlot("path", DatosSegCam, kind=Kind.STREAM),
        InputSlot("task", TaskData, kind=Kind.STREAM),
        OutputSlot("telemetry", RobotTelemetry, safety=Safety.UNSAFE, priority="interactive_low"),
        OutputSlot("imu_raw", ImuRaw, kind=Kind.STREAM),
        OutputSlot("state", UquadState, safety=Safety.UNSAFE),
        OutputSlot("control", MotorCommandLog, kind=Kind.STREAM),
        OutputSlot("error", ErrorReport),
        OutputSlot(MODE_ACK_SLOT, ModeAck),
    )
    control = Control(ControlEntradaUquad, {"slot_entrada_modo": "modo", "slot_entrada_path": "path",
                                            "slot_entrada_task": "task"})
    error_slot = "error"
    conf_errors = staticmethod(conf_errors)
    """The uQuad's check of its part of the robot .conf (``cromat launch --check``, ``cromat conf check``)."""
    param_errors = staticmethod(uquad_param_errors)
    """The uQuad's check of its manifest ``params`` (``cromat launch --check``, with file:line)."""

    def __init__(self, context: Any) -> None:
        super().__init__(context)
        if not context.conf:
            raise ConfError("the uquad module needs the robot .conf", path="<none>")
        p = load_uquad_params(context.params)  # ParamError: exit 78, not restarted
        self.cfg = load_config(context.conf)
        self.imu_url = p.imu or self.cfg.values.IMU_PORT
        self.gps_url = p.gps or self.cfg.values.GPS_PORT
        self.motor_url = p.motor
        self.clock_mode = p.clock
        self.lockstep = self.sim is not None
        """A lockstep simulation: the flight loop's time is the frames' and its stamps are simulated time."""
        if self.lockstep and self.clock_mode != "imu":
            self.log.warning("lockstep: the flight loop times itself by the simulator's IMU frames (clock = imu), "
                             "not by the wall clock its params ask for")
            self.clock_mode = "imu"
        self.ledger = FlightLedger()
        self._epoch: float | None = None
        """Lockstep: the simulation's epoch (wall time of simulated 0), once the clock has it."""
        self.record_raw = p.record_raw
        self.nice = p.nice
        self.core = FlightCore(self.cfg, load_calibration(self.cfg.imu_calib_file), p.controller)
        self.home = Home(self.cfg.home_lat, self.cfg.home_lon, self.cfg.home_alt)
        self._inbox: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()
        self._outbox: queue.Queue[tuple[str, Any] | None] = queue.Queue(OUTBOX_SIZE)
        self.outbox_dropped = 0
        self._thread: threading.Thread | None = None
        self._writer: threading.Thread | None = None
        self._wake_r, self._wake_w = os.pipe()
        self.latencies: list[float] = []
        self.driver_error = ""

    # ------------------------------------------------------------ bus side

    def on_start(self) -> None:
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        gc.freeze()  # what start-up made (modules, casadi, the session) is never scanned again: short collections
        if self.nice:
            renice_process(self.nice, self.log)
        self._writer = threading.Thread(target=self._write_bus, name="uquad.bus_writer", daemon=True)
        self._writer.start()
        self._thread = threading.Thread(target=self._flight, name="uquad.flight", daemon=True)
        self._thread.start()

    def on_stop(self) -> None:
        os.write(self._wake_w, b"x")
        if self._thread is not None:
            self._thread.join(5.0)
        try:
            self._outbox.put(None, timeout=1.0)
        except queue.Full:
            pass
        if self._writer is not None:
            self._writer.join(5.0)

    def _send(self, slot: str, value: Any) -> None:
        """Queue a datum for the bus writer thread; never blocks the flight loop."""
        try:
            self._outbox.put_nowait((slot, value))
        except queue.Full:
            self.outbox_dropped += 1
        else:
            self.ledger.queued += 1

    def _write_bus(self) -> None:
        while (item := self._outbox.get()) is not None:
            try:
                self.publish(*item)
            except Exception:  # a closed session at shutdown: nothing more to write
                self.log.exception("publishing %s failed", item[0])
                return
            finally:
                self.ledger.published += 1

    def lockstep_busy(self) -> str:
        """Lockstep: data the flight thread queued for the bus that the writer has not published yet."""
        return self.ledger.busy()

    def lockstep_counts(self) -> dict[str, int]:
        """Lockstep: the device links' bytes and commands the flight thread has finished with (the simulator
        compares them with its own), and what left the module (modules/uquad/lockstep.py)."""
        return self.ledger.counts(self.error_count)

    def _stamp(self, flight_now: float) -> float:
        """A datum's stamp: the wall clock, or in lockstep the simulated time of the frame it comes from."""
        if self.lockstep:
            if self._epoch is None:  # fixed once the stepper's time has reached the clock (before any frame)
                self._epoch = sim_epoch(self.bbcs_clock)
            if self._epoch is not None:
                return self._epoch + flight_now
        return time.time()

    def _link_now(self, flight_now: float) -> float:
        """What the driver link's ack timeout is measured on: the wall clock (its acks arrive in real time), or in
        lockstep the frames' time (the simulator waits for each set-point, so an ack is late only in it)."""
        return flight_now if self.lockstep else time.monotonic()

    def on_modo(self, m: UquadMode) -> None:
        """Queue the mode for the flight loop, then answer it (``ack = true`` in the manifest): the manager replies
        to the task only after this answer, so the RAL's path for the task is queued behind its mode, never ahead of
        it (a hold's mode arriving after a goto's path would clear the waypoints: docs/bus.md, "Mode and data in
        order"). After a driver error only a landing is taken; anything else is refused, and the task with it."""
        mode = Mode(m.modo)
        if self.driver_error and mode is not Mode.LAND:
            why = f"mode {mode.name} refused after a driver error ({self.driver_error}): only a landing is taken"
            self.publish(MODE_ACK_SLOT, ModeAck(mode=mode_echo(m), accepted=False,
                                                code=int(UquadErrorCode.DRIVER_ERROR), reason=why))
            return
        self._inbox.put(("mode", mode))
        self.publish(MODE_ACK_SLOT, ModeAck(mode=mode_echo(m), accepted=True))

    def on_path(self, d: DatosSegCam) -> None:
        if d.n_points != len(d.puntos):
            self.report_error(UquadErrorCode.BAD_PATH, f"path says {d.n_points} points, carries {len(d.puntos)}")
            return
        points = [np.array(self.home.to_local(pt.latitud, pt.longitud, pt.altura)) for pt in d.puntos]
        self._inbox.put(("path", points))

    def on_task(self, d: TaskData) -> None:
        self._inbox.put(("task", d.params))

    # ------------------------------------------------------------ flight thread

    def _flight(self) -> None:
        try:
            self._loop()
        except Exception as exc:  # the loop must never die silently
            self.log.exception("flight loop failed")
            self.report_error(UquadErrorCode.IMU_LOST, f"flight loop stopped: {exc}")
            self.request_stop()  # no flight loop, no module: the process exits and the manager reports it

    def _loop(self) -> None:
        v = self.cfg.values
        imu = Stream(self.imu_url, v.IMU_BAUD)
        parser = ImuParser(v.IMU_MODE)
        gps = Stream(self.gps_url) if v.GPS_MODE == "real" and self.gps_url else None
        nmea = NmeaReader()
        fake_gps = FakeGps(v.GPS_MODE, v.GPS_FAKE_RANGE) if v.GPS_MODE in ("zeros", "random") else None
        motor = None
        if self.motor_url != "sim":
            link = Stream(self.motor_url)
            assert link.socket is not None
            motor = MotorClient(link.socket, v.MOTOR_MIN, v.MOTOR_MAX, v.MOTOR_ACK_TIMEOUT)
            self.ledger.motor_tx = 0
        raw_log = open(self.record_raw, "ab") if self.record_raw else None  # noqa: SIM115 - closed below
        self.parser, self.nmea, self.motor = parser, nmea, motor
        fds = [imu.fileno(), self._wake_r] + ([gps.fileno()] if gps else []) + ([motor.fileno()] if motor else [])
        next_tel = 0.0
        frames = 0
        try:
            while not self.stopping:
                ready, _, _ = select.select(fds, [], [], 0.5)
                self._apply_inbox()
                now = time.monotonic()
                if motor is not None and motor.fileno() in ready:
                    motor.on_readable(now)
                if gps is not None and gps.fileno() in ready:
                    try:
                        gps_data = gps.read()
                    except EOFError as exc:  # without GPS the estimator goes on (the seed's reduced mode)
                        self.log.warning("GPS lost, flying on the IMU and barometer: %s", exc)
                        fds.remove(gps.fileno())
                        gps.close()
                        gps = None
                        gps_data = b""
                    for fix in nmea.feed(gps_data):
                        self.core.on_gps(LocalGps(*self.home.to_local(fix.lat, fix.lon, fix.alt), fix.ve, fix.vn))
                    self.ledger.gps_rx += len(gps_data)
                if imu.fileno() not in ready:
                    continue
                data, lost = read_available(imu)  # frames read with the end are handled, then the loop stops
                t_read = time.monotonic()
                frames_before = frames
                batch = parser.feed(data)
                # on the wall clock, what was read together is one step (the seed's main); on the IMU's clock
                # (replay of a raw log, faster-than-real-time simulation) every frame is a step of its own
                groups = [batch] if self.clock_mode == "wall" else [[f] for f in batch]
                for group in groups:
                    if not group or self.stopping:
                        break
                    frames += len(group)
                    now = flight_time(frames) if self.clock_mode == "imu" else t_read
                    refusals = self.core.stats.calibration_refusals
                    cuts = self.core.stats.tumble_cuts
                    cmd = self.core.on_frames(group, now)  # the estimator and the law run once per read
                    if cmd is not None:
                        self._command(cmd, now, t_read, motor)  # first: nothing else waits in front of it
                    if self.core.stats.tumble_cuts != cuts:  # motors cut (the zeros above): tell the RAL now
                        self._publish_telemetry(tumbling=True, stamp=self._stamp(now))
                        self.report_error(UquadErrorCode.LOSS_OF_CONTROL, self.core.stats.errors[-1])
                    if self.core.stats.calibration_refusals != refusals:
                        self.report_error(UquadErrorCode.CALIBRATION_REFUSED, self.core.stats.errors[-1])
                    if fake_gps is not None and self.core.calibrated and (g := fake_gps.poll(now)) is not None:
                        self.core.on_gps(g)
                    stamp = self._stamp(now)
                    for frame in group:
                        self._send("imu_raw", ImuRaw(stamp=stamp, **frame._asdict()))
                    if frames // STATE_EVERY != (frames - len(group)) // STATE_EVERY and self.core.calibrated:
                        self._publish_state(stamp)
                if raw_log is not None:
                    raw_log.write(data)
                if self.lockstep:  # every TELEMETRY_EVERY frames of simulated time
                    if crossed(frames_before - TELEMETRY_PHASE, frames - TELEMETRY_PHASE, TELEMETRY_EVERY):
                        self._publish_telemetry(stamp=self._stamp(flight_time(frames)))
                else:
                    wall = time.monotonic()
                    if wall >= next_tel:
                        next_tel = wall + TELEMETRY_PERIOD_S
                        self._publish_telemetry()
                if lost is not None:
                    self.report_error(UquadErrorCode.IMU_LOST, str(lost))
                    break
                self.ledger.imu_rx += len(data)  # last: everything this read brought is handled and queued
        finally:
            st = parser.stats
            self.log.info("flight loop stopped: frames=%d bad_frames=%d bytes_discarded=%d control_actions=%d",
                          st.frames, st.bad_frames, st.bytes_discarded, self.core.stats.control_actions)
            self.log.info("bus data dropped by the outbox (bus slower than the IMU): %d", self.outbox_dropped)
            if motor is not None:
                motor.send(time.monotonic(), [0.0] * 4)
                motor.close()
            imu.close()
            if gps is not None:
                gps.close()
            if raw_log is not None:
                raw_log.close()

    def _apply_inbox(self) -> None:
        while True:
            try:
                kind, value = self._inbox.get_nowait()
            except queue.Empty:
                return
            if kind == "mode":
                if self.driver_error and value is not Mode.LAND:
                    self.log.warning("mode %s ignored after a driver error", value.name)
                    continue
                self.core.set_mode(value)
            elif kind == "task":
                why = apply_task(self.core.planner, value)
                if why:
                    self.report_error(UquadErrorCode.TASK_REFUSED, why)
            else:
                self.core.set_waypoints(value)

    def _command(self, cmd: np.ndarray, now: float, t_read: float, motor: MotorClient | None) -> None:
        """Hand the command to the driver link; the latency ends there (the seed's IMU → control action), and only
        then are the driver's acks read and checked and the action logged."""
        sent = list(cmd)
        if motor is not None:  # the link's ack timeout on the wall clock, in lockstep on the frames' (_link_now)
            sent = motor.send(self._link_now(now), cmd)
            self.ledger.motor_tx = motor.sent
        latency = time.monotonic() - t_read
        self.latencies.append(latency)
        if motor is not None:
            motor.on_readable(time.monotonic())  # acks already here count, even while a burst of frames is handled
            error = motor.check(self._link_now(now))
            if error and not self.driver_error:
                self.driver_error = error
                action = self.cfg.values.MOTOR_ERROR_ACTION
                self.report_error(UquadErrorCode.DRIVER_ERROR, f"{error}: {action}")
                if action == "cut":
                    self.core.set_mode(Mode.IDLE)
                    motor.send(self._link_now(now), [0.0] * 4)
                    self.ledger.motor_tx = motor.sent
                else:
                    self.core.set_mode(Mode.LAND)
            elif (self.driver_error and self.core.planner.mode is Mode.IDLE and not any(sent)
                  and motor.recover(self._link_now(now))):
                self.log.warning("the motor driver acknowledges every command in time again, on the ground with the "
                                 "motors stopped: the driver error (%s) is cleared", self.driver_error)
                self.driver_error = ""
        self._send("control", MotorCommandLog(stamp=self._stamp(now), speeds=_vec(sent),
                                                ts=float(self.core.stats.last_ts), latency_s=latency))

    def _publish_state(self, stamp: float) -> None:
        k = self.core.kalman
        self._send("state", UquadState(
            stamp=stamp, position=_vec(k.position), velocity=_vec(k.velocity), euler=_vec(k.euler),
            rates=_vec(self.core.gyro), acc_bias=_vec(k.acc_bias), mode=int(self.core.planner.mode),
            setpoint=_vec(self.core.planner.sp)))

    def _publish_telemetry(self, tumbling: bool = False, stamp: float | None = None) -> None:
        """The generic telemetry; ``tumbling``: sent at the cut, still airborne (it is: falling, motors off) so the
        RAL judges the attitude that made it (the planner is idle from now on); airborne, with 706, until the IMU
        shows it at rest (``FallWatch``). ``stamp``: now (the wall clock)
        unless given (lockstep: the simulated time of the frame it describes)."""
        core = self.core
        stamp = time.time() if stamp is None else stamp
        if not core.calibrated:
            self._send("telemetry", RobotTelemetry(stamp=stamp, mode=int(Mode.IDLE), mode_name="calibrating",
                                                   airborne=False))
            return
        k = core.kalman
        e, n, u = (float(c) for c in k.position)
        lat, lon, alt = self.home.to_geo(e, n, u)
        psi, phi, theta = (float(a) for a in k.euler)
        planner = core.planner
        queued = len(planner.waypoints) if planner.mode is Mode.GOTO else 0
        self._send("telemetry", RobotTelemetry(
            stamp=stamp,
            position=GeoPoint(lat=lat, lon=lon, alt=alt),
            attitude=Attitude(roll=float(np.degrees(psi)), pitch=float(np.degrees(phi)), yaw=heading_deg(theta)),
            velocity=VelocityNED(vn=float(k.velocity[1]), ve=float(k.velocity[0]), vd=-float(k.velocity[2])),
            heading_deg=heading_deg(theta),
            mode=int(planner.mode), mode_name=planner.mode.name.lower(),
            airborne=planner.airborne or tumbling or core.fall.falling, waypoints_queued=queued,
            error_code=(UquadErrorCode.LOSS_OF_CONTROL if tumbling or core.fall.falling else
                        UquadErrorCode.DRIVER_ERROR if self.driver_error else 0),
        ))


def renice_process(nice: int, log: Any) -> None:
    """Every thread of this process (Linux niceness is per thread) to ``nice``; threads made later inherit it.
    All of them, not only the flight thread: a bus thread holding the interpreter lock at a lower priority would
    hold the flight thread back (priority inversion)."""
    try:
        for tid in os.listdir("/proc/self/task"):
            os.setpriority(os.PRIO_PROCESS, int(tid), nice)
    except (PermissionError, FileNotFoundError, ProcessLookupError) as exc:
        log.warning("cannot set the process's niceness to %d (%s): running at the default", nice, exc)


def _vec(values: Any) -> tuple[float, ...]:
    return tuple(float(v) for v in values)


def main(argv: list[str] | None = None) -> int:
    return UquadModule.main(argv)


__all__ = ["UquadModule", "main", "model"]
