"""The DSP's behaviour, as docs/dsp_protocol.md describes it, with no I/O and no clock of its own.

``handle(frame, link_time)`` applies one received command and returns its ACK (with duplicate suppression);
``step(dt)`` advances the flight (guidance + vehicle model) by ``dt`` seconds and returns what the DSP sends
on its own (telemetry when due, ERROR messages). The simulator's server feeds it bytes and time; tests drive
it directly.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from bbcs.contracts import dsp as p
from bbcs.geodesy import LocalFrame
from modules.dsp.codec import DspDecodeError, decode
from modules.dsp.framing import Frame
from modules.dsp.sim.vehicle import ROTOR_FLIGHT_RPM, Vehicle, VehicleParams, pid_gains, wrap_deg

FLIGHT_MODES = frozenset({p.Mode.PATH_AUTO_HEADING, p.Mode.PATH_GIVEN_HEADING, p.Mode.ONBOARD_FOLLOWER,
                          p.Mode.TAKE_OFF, p.Mode.LANDING, p.Mode.BRIDGE})
PATH_MODES = frozenset({p.Mode.PATH_AUTO_HEADING, p.Mode.PATH_GIVEN_HEADING})
BRIDGE_MODES = frozenset({p.Mode.ONBOARD_FOLLOWER, p.Mode.BRIDGE})


@dataclass(frozen=True)
class DspParams:
    home_lat: float = 37.4117  # take-off point (Seville); ground level = home_alt
    home_lon: float = -6.0025
    home_alt: float = 12.0  # m MSL
    takeoff_height: float = 10.0  # m above the ground
    takeoff_speed: float = 1.0  # m/s
    land_speed: float = 0.7  # m/s
    arrive_h: float = 1.5  # m: waypoint reached horizontally
    arrive_v: float = 1.0  # m: and vertically
    queue_capacity: int = p.WAYPOINT_QUEUE_CAPACITY
    duplicate_window_s: float = 2.0  # link time
    low_battery_v: float = 21.0
    position_gain: float = 0.8  # 1/s, position → velocity command
    brake_accel: float = 1.5  # m/s², planned deceleration before a waypoint
    pan_tilt_rate: float = 90.0  # deg/s


class Waypoint(NamedTuple):
    lat: float
    lon: float
    alt: float
    local: np.ndarray  # north, east, up from home [m]


class HandleResult(NamedTuple):
    ack: p.Ack
    command: p.Message | None  # None for a retransmission or an undecodable payload
    duplicate: bool


class DspMachine:
    """Mode, tracking flag, waypoint queue, path validity, speed, heading, pan & tilt, errors, the flight."""

    def __init__(self, params: DspParams | None = None, vehicle_params: VehicleParams | None = None) -> None:
        self.params = params or DspParams()
        self.vehicle = Vehicle(vehicle_params)
        self.time_s = 0.0
        self.mode = p.Mode.SEMI_AUTOMATIC
        self.tracking = False
        self.path_valid = False
        self.queue: deque[Waypoint] = deque()
        self.speed_cmd = 0.0
        self.heading_ref: float | None = None
        self.state_tx = False
        self.period_ms = 50
        self.telemetry_mask = 0
        self.error_code = 0
        self.heli_type: p.HeliType | None = None
        self.pids: dict[p.Axis, p.SetPid] = {}
        self.pt_mode = p.PanTiltMode.HOLD
        self.pan = 0.0
        self.tilt = 0.0
        self.pt_refs = (0.0, 0.0)
        self.pt_target: np.ndarray | None = None
        self.pt_hold = (0.0, 0.0)  # world azimuth, tilt
        self.bridge_target: np.ndarray | None = None
        self.bridge_heading: float | None = None
        self.bridge_rpm = ROTOR_FLIGHT_RPM
        self.manoeuvre_stopped = False
        self.waypoints_reached = 0
        self.scheduled_errors: list[tuple[float, int]] = []
        self._hold_point = np.zeros(3)
        self._hold_heading = 0.0
        self._last_command: tuple[tuple[int, int, bytes], float, int] | None = None
        self._next_telemetry_s = 0.0
        self._outbox: list[p.Message] = []
        self._battery_reported = False
        self._last_rx_error_s = -math.inf
        self._home = LocalFrame(self.params.home_lat, self.params.home_lon, self.params.home_alt)

    # --- geometry ------------------------------------------------------------------------------------------

    def to_local(self, lat: float, lon: float, alt: float) -> np.ndarray:
        """Degrees/metres MSL → north, east, up from home (bbcs.geodesy's frame at home: fine over a few km)."""
        east, north, up = self._home.to_local(lat, lon, alt)
        return np.array([north, east, up])

    def to_global(self, local: np.ndarray) -> tuple[float, float, float]:
        lat, lon, alt = self._home.to_geo(float(local[1]), float(local[0]), float(local[2]))
        return lat, lon, alt

    # --- commands ------------------------------------------------------------------------------------------

    def handle(self, frame: Frame, link_time: float) -> HandleResult:
        """Apply one received command frame; a retransmission within the window is answered, not redone."""
        key = (frame.msg_id, frame.seq, frame.payload)
        last = self._last_command
        if last is not None and last[0] == key and link_time - last[1] <= self.params.duplicate_window_s:
            return HandleResult(p.Ack(acked_id=frame.msg_id, acked_seq=frame.seq, status=last[2]), None, True)
        msg: p.Message | None = None
        try:
            msg = decode(frame)
            p.check(msg)
            status = self._apply(msg)
        except (DspDecodeError, p.DspValueError):
            status = int(p.ErrorCode.OUT_OF_RANGE)
        if status:
            self.error_code = status
        self._last_command = (key, link_time, status)
        return HandleResult(p.Ack(acked_id=frame.msg_id, acked_seq=frame.seq, status=status), msg, False)

    def _apply(self, msg: p.Message) -> int:
        E = p.ErrorCode
        st = self.vehicle.state
        if isinstance(msg, p.SetSpeed):
            self.speed_cmd = min(msg.speed, self.vehicle.params.max_speed)
        elif isinstance(msg, p.SetTelemetryMask):
            self.telemetry_mask = msg.mask
        elif isinstance(msg, p.SetStateTransmission):
            if msg.enable and not self.state_tx:
                self._next_telemetry_s = self.time_s
            self.state_tx, self.period_ms = msg.enable, msg.period_ms
        elif isinstance(msg, p.ClearError):
            self.error_code = 0
        elif isinstance(msg, p.SetTracking):
            if self.tracking and not msg.enable:
                self._hold_here()
            self.tracking = msg.enable
        elif isinstance(msg, p.InvalidatePath):
            self.queue.clear()
            self.path_valid = False
            if self.mode in PATH_MODES:
                self._hold_here()
        elif isinstance(msg, p.SetHelicopterType):
            self.heli_type = msg.heli_type
        elif isinstance(msg, p.SetPid):
            self.pids[msg.axis] = msg
            self.vehicle.set_pid(msg.axis, pid_gains(msg))  # the simulated loops fly on the gains sent
        elif isinstance(msg, p.SetMode):
            if msg.mode in FLIGHT_MODES and self.heli_type is None:
                return E.NOT_CONFIGURED
            self.mode = msg.mode
            self.manoeuvre_stopped = False
            self.bridge_target = None
            self.bridge_heading = None
            if msg.mode == p.Mode.PATH_GIVEN_HEADING:
                self.heading_ref = st.heading
            self._hold_here()
        elif isinstance(msg, p.SetHeading):
            self.heading_ref = msg.heading_deg
        elif isinstance(msg, p.AddWaypoint):
            if len(self.queue) >= self.params.queue_capacity:
                return E.QUEUE_FULL
            self.queue.append(Waypoint(msg.lat, msg.lon, msg.alt, self.to_local(msg.lat, msg.lon, msg.alt)))
            self.path_valid = True
        elif isinstance(msg, p.SetRefs):
            if self.mode not in BRIDGE_MODES:
                return E.WRONG_MODE
            psi = math.radians(st.heading)
            north = msg.error_longitudinal * math.cos(psi) - msg.error_lateral * math.sin(psi)
            east = msg.error_longitudinal * math.sin(psi) + msg.error_lateral * math.cos(psi)
            self.bridge_target = np.array([st.pos[0] + north, st.pos[1] + east,
                                           max(0.0, msg.ref_altura - self.params.home_alt)])
            self.bridge_heading = wrap_deg(math.degrees(msg.ref_heading))
            self.bridge_rpm = msg.ref_rpm_motor
        elif isinstance(msg, p.SetPanTiltMode):
            if msg.mode == p.PanTiltMode.HOLD:
                self.pt_hold = (wrap_deg(self.pan + st.heading), self.tilt)
            self.pt_mode = msg.mode
        elif isinstance(msg, p.SetPanTiltAngles):
            if self.pt_mode != p.PanTiltMode.ANGLES:
                return E.WRONG_MODE
            self.pt_refs = (msg.pan_deg, msg.tilt_deg)
        elif isinstance(msg, p.SetPanTiltTarget):
            if self.pt_mode != p.PanTiltMode.TARGET:
                return E.WRONG_MODE
            self.pt_target = self.to_local(msg.lat, msg.lon, msg.alt)
        elif isinstance(msg, p.Abort):
            self.queue.clear()
            self.path_valid = False
            self.manoeuvre_stopped = True
            self.bridge_target = None
            self._hold_here()
        elif isinstance(msg, p.Ping):
            pass  # the ACK is the answer
        else:
            return E.OUT_OF_RANGE  # a reply id sent to the DSP: not a command
        return 0

    def _hold_here(self) -> None:
        """Station-keep where the aircraft can stop from its present velocity."""
        st = self.vehicle.state
        stop = st.pos.copy()
        speed = st.ground_speed
        if speed > 0.05:
            stop[:2] += st.vel[:2] * (speed / (2.0 * self.params.brake_accel))
        if not st.airborne:
            stop[2] = 0.0
        self._hold_point = stop
        self._hold_heading = st.heading

    # --- errors --------------------------------------------------------------------------------------------

    def raise_error(self, code: int, related_id: int = 0) -> None:
        """Latch ``code`` and queue an ERROR message for the PC."""
        self.error_code = code
        self._outbox.append(p.DspError(time_ms=self.time_ms, code=code, related_id=related_id))

    def note_rx_errors(self) -> None:
        """The receiver dropped bytes: report RX_ERRORS, at most once per second."""
        if self.time_s - self._last_rx_error_s >= 1.0:
            self._last_rx_error_s = self.time_s
            self.raise_error(p.ErrorCode.RX_ERRORS)

    # --- flight --------------------------------------------------------------------------------------------

    @property
    def time_ms(self) -> int:
        return round(self.time_s * 1000.0) & 0xFFFFFFFF

    @property
    def following(self) -> bool:
        return self.mode in PATH_MODES and self.tracking and self.path_valid and bool(self.queue)

    def step(self, dt: float) -> list[p.Message]:
        """Advance the DSP by ``dt`` seconds; returns the frames it sends on its own (telemetry, errors)."""
        self.time_s += dt
        v_cmd, heading_cmd, rpm_cmd = self._guidance()
        self.vehicle.step(dt, v_cmd, heading_cmd, rpm_cmd)
        self._pan_tilt(dt)
        st = self.vehicle.state
        if st.battery_v < self.params.low_battery_v and not self._battery_reported:
            self._battery_reported = True
            self.raise_error(p.ErrorCode.LOW_BATTERY)
        while self.scheduled_errors and self.scheduled_errors[0][0] <= self.time_s:
            self.raise_error(self.scheduled_errors.pop(0)[1])
        out, self._outbox = self._outbox, []
        if self.state_tx and self.time_s + 1e-9 >= self._next_telemetry_s:
            out.append(self.telemetry())
            period = self.period_ms / 1000.0
            self._next_telemetry_s = max(self._next_telemetry_s + period, self.time_s - period)
        return out

    def _approach(self, target: np.ndarray, speed: float, climb: float) -> np.ndarray:
        """Velocity command toward ``target``: ≤ speed, slowing down so the aircraft stops on it."""
        par = self.params
        d = target - self.vehicle.state.pos
        dist = math.hypot(d[0], d[1])
        v = np.zeros(3)
        if dist > 1e-6:
            mag = min(speed, math.sqrt(2.0 * par.brake_accel * dist), par.position_gain * dist)
            v[:2] = d[:2] * (mag / dist)
        v[2] = min(max(par.position_gain * d[2], -climb), climb)
        return v

    def _guidance(self) -> tuple[np.ndarray, float, float]:
        par = self.params
        st = self.vehicle.state
        vpar = self.vehicle.params
        spinning = self.heli_type is not None and (self.mode in FLIGHT_MODES or st.airborne)
        rpm = ROTOR_FLIGHT_RPM if spinning else 0.0
        if self.following:
            wp = self.queue[0]
            d = wp.local - st.pos
            if math.hypot(d[0], d[1]) < par.arrive_h and abs(d[2]) < par.arrive_v:
                self.queue.popleft()
                self.waypoints_reached += 1
                if not self.queue:
                    self._hold_point = wp.local.copy()
                    self._hold_heading = st.heading
        if self.following:
            wp = self.queue[0]
            d = wp.local - st.pos
            if self.mode == p.Mode.PATH_GIVEN_HEADING and self.heading_ref is not None:
                heading = self.heading_ref
            elif math.hypot(d[0], d[1]) > 2.0:
                heading = math.degrees(math.atan2(d[1], d[0]))  # face the next waypoint
            else:
                heading = st.heading
            self._hold_heading = heading
            speed = min(self.speed_cmd, vpar.max_speed)
            if self.mode == p.Mode.PATH_AUTO_HEADING:  # turn toward the waypoint before speeding up
                speed *= max(0.1, math.cos(math.radians(wrap_deg(heading - st.heading))))
            return self._approach(wp.local, speed, vpar.max_climb), heading, rpm
        if self.mode == p.Mode.TAKE_OFF and not self.manoeuvre_stopped:
            target = np.array([self._hold_point[0], self._hold_point[1], par.takeoff_height])
            return self._approach(target, vpar.max_speed, par.takeoff_speed), self._hold_heading, rpm
        if self.mode == p.Mode.LANDING and not self.manoeuvre_stopped:
            target = np.array([self._hold_point[0], self._hold_point[1], -1.0])  # push onto the ground
            if not st.airborne and st.vel[2] == 0.0:
                rpm = 0.0  # down: idle the rotor
            return self._approach(target, vpar.max_speed, par.land_speed), self._hold_heading, rpm
        if self.mode in BRIDGE_MODES and self.bridge_target is not None:
            heading = self.bridge_heading if self.bridge_heading is not None else self._hold_heading
            v_cmd = self._approach(self.bridge_target, vpar.max_speed, vpar.max_climb)
            return v_cmd, heading, self.bridge_rpm
        if self.mode == p.Mode.SEMI_AUTOMATIC and not st.airborne:
            rpm = 0.0
        heading = self._hold_heading
        if self.mode == p.Mode.PATH_GIVEN_HEADING and self.heading_ref is not None:
            heading = self.heading_ref  # mode 1 holds the given heading also while it is not following
        return self._approach(self._hold_point, vpar.max_speed, vpar.max_climb), heading, rpm

    def _pan_tilt(self, dt: float) -> None:
        st = self.vehicle.state
        if self.pt_mode == p.PanTiltMode.ANGLES:
            pan_ref, tilt_ref = self.pt_refs
        elif self.pt_mode == p.PanTiltMode.TARGET and self.pt_target is not None:
            d = self.pt_target - st.pos
            pan_ref = wrap_deg(math.degrees(math.atan2(d[1], d[0])) - st.heading)
            tilt_ref = math.degrees(math.atan2(d[2], math.hypot(d[0], d[1])))
        elif self.pt_mode == p.PanTiltMode.HOLD:
            pan_ref, tilt_ref = wrap_deg(self.pt_hold[0] - st.heading), self.pt_hold[1]
        else:
            return
        step = self.params.pan_tilt_rate * dt
        pan_err = wrap_deg(pan_ref - self.pan)
        self.pan = max(-180.0, min(180.0, self.pan + max(-step, min(step, pan_err))))
        tilt_ref = max(-90.0, min(90.0, tilt_ref))
        self.tilt += max(-step, min(step, tilt_ref - self.tilt))

    # --- telemetry -----------------------------------------------------------------------------------------

    def telemetry(self) -> p.Telemetry:
        """The state frame for the current mask."""
        st = self.vehicle.state
        mask = self.telemetry_mask
        F = p.TelemetryField
        fields: dict[str, object] = {}
        if mask & F.POSITION:
            lat, lon, alt = self.to_global(st.pos)
            fields["position"] = p.TelPosition(lat=lat, lon=lon, alt=alt)
        if mask & F.ATTITUDE:
            fields["attitude"] = p.TelAttitude(roll=st.roll, pitch=st.pitch, yaw=st.heading)
        if mask & F.VELOCITY:
            fields["velocity"] = p.TelVelocity(vn=float(st.vel[0]), ve=float(st.vel[1]), vd=float(-st.vel[2]))
        if mask & F.ANGULAR_RATE:
            fields["angular_rate"] = p.AngularRate(p=st.roll_rate, q=st.pitch_rate, r=st.yaw_rate)
        if mask & F.HEADING:
            fields["heading"] = st.heading
        if mask & F.STATUS:
            fields["status"] = p.DspStatus(mode=int(self.mode), tracking=self.tracking,
                                           path_valid=self.path_valid, airborne=st.airborne,
                                           queue_length=min(len(self.queue), 0xFFFF))
        if mask & F.NAV:
            if self.queue:
                wp = self.queue[0]
                dist = float(np.linalg.norm(wp.local - st.pos))
                fields["nav"] = p.NavTarget(lat=wp.lat, lon=wp.lon, alt=wp.alt, distance=dist)
            else:
                fields["nav"] = p.NavTarget(lat=0.0, lon=0.0, alt=0.0, distance=-1.0)
        if mask & F.SPEED:
            fields["speed"] = p.SpeedInfo(commanded=self.speed_cmd, ground=st.ground_speed)
        if mask & F.PAN_TILT:
            fields["pan_tilt"] = p.PanTiltState(mode=int(self.pt_mode), pan=self.pan, tilt=self.tilt)
        if mask & F.ERROR:
            fields["error_code"] = self.error_code
        if mask & F.ENGINE:
            fields["engine"] = p.Engine(rotor_rpm=st.rotor_rpm, battery_v=st.battery_v)
        return p.Telemetry(time_ms=self.time_ms, **fields)  # type: ignore[arg-type]
