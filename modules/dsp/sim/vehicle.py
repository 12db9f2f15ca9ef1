"""A single-rotor helicopter flown by the DSP's own loops, integrated with an injected time step.

The rigid body is :mod:`control.heli` (casadi, written once; the onboard follower derives its model from it).
On top of it run the controllers the DSP was sent: one :class:`control.pid.Pid` per ``SET_PID`` axis, with the
seed-002 anti-windup, at ``control_dt`` (≤ 10 ms) sub-steps whose sampling period is measured from this
vehicle's own clock. The cascade (docs/dsp_protocol.md, "The simulator's flight control loops"):

- guidance (the machine) gives a velocity command; a reference point moves at that velocity; the
  ``LONGITUDINAL``/``LATERAL`` PIDs turn its along/cross-track offset (body axes, metres) into pitch/roll
  references (degrees) on top of the trim attitude for the commanded velocity;
- ``ROLL``/``PITCH`` turn attitude errors (degrees) into cyclic (−1…1); ``YAW`` the heading error into tail
  rotor; ``ALTITUDE`` the height error (m) into collective (its ``offset`` is the hover collective);
  ``ROTOR_RPM`` the rotor-speed error into throttle (its ``offset`` is the cruise throttle).

Actuator limits are the PIDs' output saturations; the rotor lags through flapping, collective and engine time
constants; the wind is a seeded mean plus first-order (Gauss-Markov) gusts. The DSP's envelope protection
keeps the protocol's speed guarantees: horizontal speed never exceeds the commanded speed (the limit follows a
falling command no faster than ``max_accel``), nor vertical speed the commanded climb or descent rate.
Local frame: north, east, up (metres from the home point); angles in telemetry are degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from bbcs.contracts.dsp import Axis, SetPid
from control.heli import NU, NW, NX, HeliParams, rk4_step
from control.pid import Pid, PidGains

G = 9.80665
ROTOR_FLIGHT_RPM = 1500.0
ROTOR_LIFT_RPM = 1200.0  # below this the aircraft cannot leave the ground
ENVELOPE_FLOOR = 0.5  # m/s: below this the envelope protection never clips (hover and small corrections)
THROTTLE_FULL_RPM = ROTOR_FLIGHT_RPM / 0.55  # engine: steady rotor speed at full throttle, no load


def wrap_deg(angle: float) -> float:
    """Angle in degrees wrapped into [-180, 180)."""
    wrapped = (angle + 180.0) % 360.0 - 180.0
    return wrapped - 360.0 if wrapped >= 180.0 else wrapped


def default_pids() -> dict[Axis, PidGains]:
    """The DSP's built-in groups (the same as bbcs_conf/uav1.conf), used for every axis not sent.

    ``th_dist`` and ``th_max`` (seed 002's two thresholds the ``.conf`` has no field for) are built in.
    """
    return {
        Axis.ROLL: PidGains(0.045, 0.010, 0.008, 0, 20, -20, 0, 0, 1, -1, th_dist=20.0, th_max=10.0),
        Axis.PITCH: PidGains(0.050, 0.012, 0.009, 0, 20, -20, 0, 0, 1, -1, th_dist=20.0, th_max=10.0),
        Axis.YAW: PidGains(0.020, 0.004, 0.002, 0, 45, -45, 0, 0, 1, -1, th_dist=0.5, th_max=0.2),
        Axis.ALTITUDE: PidGains(0.080, 0.015, 0.040, 0, 10, -10, 0, 0.42, 1, 0, th_dist=1.0, th_max=0.5),
        Axis.LONGITUDINAL: PidGains(1.2, 0.05, 0.60, 0, 50, -50, 0, 0, 15, -15, th_dist=10.0, th_max=2.0),
        Axis.LATERAL: PidGains(1.0, 0.05, 0.50, 0, 50, -50, 0, 0, 15, -15, th_dist=10.0, th_max=2.0),
        Axis.ROTOR_RPM: PidGains(0.0008, 0.0002, 0, 0, 500, -500, 1500, 0.55, 1, 0, th_dist=300.0, th_max=200.0),
    }


THRESHOLDS = {axis: (g.th_dist, g.th_max) for axis, g in default_pids().items()}


def pid_gains(group: SetPid) -> PidGains:
    """A ``SET_PID`` message → the controller's gains (docs/dsp_protocol.md, field mapping), with the built-in
    ``th_dist``/``th_max`` of its axis."""
    th_dist, th_max = THRESHOLDS.get(group.axis, (math.inf, math.inf))
    return PidGains(kp=group.kp, ki=group.ki, kd=group.kd, integral=group.integral, awu_max=group.awu_max,
                    awu_min=group.awu_min, reference=group.reference, offset=group.offset,
                    sat_high=group.sat_high, sat_low=group.sat_low, th_dist=th_dist, th_max=th_max)


@dataclass(frozen=True)
class VehicleParams:
    max_speed: float = 10.0  # m/s, airframe horizontal limit (the DSP's MAX_SPEED)
    max_climb: float = 2.0  # m/s
    max_accel: float = 2.5  # m/s², rate at which the speed envelope follows a falling command
    max_vaccel: float = 2.0  # m/s², the same vertically
    max_yaw_rate: float = 60.0  # deg/s, heading reference slew
    carrot_max: float = 8.0  # m, the most the horizontal reference point may lead the aircraft
    carrot_max_v: float = 1.5  # m, vertically
    carrot_relax: float = 0.5  # 1/s: the reference point forgets old lead (guidance closes position itself)
    rotor_tau: float = 1.0  # s, engine/rotor speed time constant
    rotor_spool_rate: float = 600.0  # rpm/s, soft-start limit of the rotor's acceleration
    control_dt: float = 0.02  # s, the DSP's inner-loop period (a step longer than this is sub-stepped)
    wind_north: float = 0.0  # m/s, mean wind (the air moves toward north)
    wind_east: float = 0.0
    gust_std: float = 0.0  # m/s, standard deviation of each horizontal gust component
    gust_tau: float = 3.0  # s, gust correlation time
    seed: int = 0
    battery_full: float = 25.2  # V (6S LiPo for the avionics)
    battery_drain: float = 0.002  # V/s while the rotor turns
    heli: HeliParams = field(default_factory=HeliParams)


@dataclass
class VehicleState:
    pos: np.ndarray = field(default_factory=lambda: np.zeros(3))  # north, east, up [m]
    vel: np.ndarray = field(default_factory=lambda: np.zeros(3))  # vn, ve, vu [m/s]
    accel: np.ndarray = field(default_factory=lambda: np.zeros(3))
    heading: float = 0.0  # degrees, 0 north, clockwise
    yaw_rate: float = 0.0  # deg/s
    roll: float = 0.0  # degrees
    pitch: float = 0.0
    roll_rate: float = 0.0  # deg/s
    pitch_rate: float = 0.0
    rotor_rpm: float = 0.0
    battery_v: float = 25.2

    @property
    def airborne(self) -> bool:
        return bool(self.pos[2] > 0.2)

    @property
    def ground_speed(self) -> float:
        return float(math.hypot(self.vel[0], self.vel[1]))


_STEPPERS: dict[HeliParams, ca.Function] = {}


def _stepper(par: HeliParams) -> ca.Function:
    """One casadi function per airframe taking one packed vector (x, u, w, h): the cheapest call from Python."""
    if par not in _STEPPERS:
        z = ca.SX.sym("z", NX + NU + NW + 1)
        f = rk4_step(par)
        _STEPPERS[par] = ca.Function("heli_packed", [z], [f(z[:NX], z[NX:NX + NU], z[NX + NU:NX + NU + NW], z[-1])])
    return _STEPPERS[par]


class Vehicle:
    """Integrates VehicleState; ``step`` is pure apart from the state it owns (no wall clock, no I/O)."""

    def __init__(self, params: VehicleParams | None = None, state: VehicleState | None = None) -> None:
        self.params = params or VehicleParams()
        self.state = state or VehicleState(battery_v=self.params.battery_full)
        self.time_s = 0.0  # this vehicle's clock: the PIDs measure their sampling period from it
        self.gains: dict[Axis, PidGains] = default_pids()
        self.pids: dict[Axis, Pid] = {axis: Pid(g) for axis, g in self.gains.items()}
        self._step_fn = _stepper(self.params.heli)
        st = self.state
        self._x = np.zeros(NX)
        self._x[0:3], self._x[3:6] = st.pos, st.vel
        self._x[6], self._x[7], self._x[8] = math.radians(st.roll), math.radians(st.pitch), math.radians(st.heading)
        self._x[14] = self.params.heli.hover_collective if st.airborne else 0.0
        self._carrot = st.pos.copy()
        self._v_ref = st.vel.copy()
        self._heading_ref = st.heading
        self._speed_limit = 0.0
        self._climb_limit = 0.0
        self._rng = np.random.default_rng(self.params.seed)
        self._gust = np.zeros(2)
        self.wind = np.array([self.params.wind_north, self.params.wind_east])

    def set_pid(self, axis: Axis, gains: PidGains) -> None:
        """A ``SET_PID`` group from the PC: replaces that axis's controller (its integral restarts)."""
        if axis not in self.gains:
            return  # PAN/TILT: the camera gimbal is kinematic in the machine, no loop to replace
        self.gains[axis] = gains
        self.pids[axis] = Pid(gains)

    def step(self, dt: float, v_cmd: np.ndarray, heading_cmd: float, rpm_cmd: float) -> None:
        """Advance ``dt`` seconds toward commanded velocity (n, e, up), heading (deg) and rotor speed (rpm)."""
        if dt <= 0:
            raise ValueError("dt must be positive")
        n = max(1, math.ceil(dt / self.params.control_dt - 1e-9))
        vel_before = self.state.vel.copy()
        for _ in range(n):
            self._substep(dt / n, np.array(v_cmd, dtype=float), heading_cmd, rpm_cmd)
        self.state.accel = (self.state.vel - vel_before) / dt

    def _wind_step(self, h: float) -> np.ndarray:
        par = self.params
        if par.gust_std > 0:
            a = math.exp(-h / par.gust_tau)
            self._gust = a * self._gust + par.gust_std * math.sqrt(1 - a * a) * self._rng.standard_normal(2)
        return self.wind + self._gust

    def _substep(self, h: float, cmd: np.ndarray, heading_cmd: float, rpm_cmd: float) -> None:
        par = self.params
        st = self.state
        x = self._x
        self.time_s += h
        now = self.time_s
        horiz = math.hypot(cmd[0], cmd[1])
        if horiz > par.max_speed:
            cmd[:2] *= par.max_speed / horiz
            horiz = par.max_speed
        cmd[2] = min(max(cmd[2], -par.max_climb), par.max_climb)
        grounded = x[2] <= 0.0
        if grounded:
            cmd[:2] = 0.0  # no sliding along the ground: lift off vertically

        # rotor speed: governor (ROTOR_RPM) → throttle → engine with soft start
        if rpm_cmd > 0:
            throttle = self.pids[Axis.ROTOR_RPM].step(now, st.rotor_rpm, sp=rpm_cmd)
        else:
            throttle = 0.0
            self.pids[Axis.ROTOR_RPM].reset()
        load = 400.0 * max(0.0, x[14] - par.heli.hover_collective)
        d_rpm = (throttle * THROTTLE_FULL_RPM - st.rotor_rpm - load) / par.rotor_tau
        st.rotor_rpm = max(0.0, st.rotor_rpm + min(d_rpm, par.rotor_spool_rate) * h)
        rpm_ratio = st.rotor_rpm / ROTOR_FLIGHT_RPM

        # reference velocity: the command shaped by the acceleration limits; a reference point (carrot) moves
        # at it, kept within reach of the aircraft
        prev_ref = self._v_ref.copy()
        dv = cmd - self._v_ref
        dvh = math.hypot(dv[0], dv[1])
        if dvh > par.max_accel * h:
            dv[:2] *= par.max_accel * h / dvh
        dv[2] = min(max(dv[2], -par.max_vaccel * h), par.max_vaccel * h)
        self._v_ref = self._v_ref + dv
        if grounded:
            self._v_ref[:2] = 0.0
        v_ref = self._v_ref
        a_ref = (v_ref - prev_ref) / h
        self._carrot = self._carrot + (v_ref - par.carrot_relax * (self._carrot - x[0:3])) * h
        lead = self._carrot[:2] - x[:2]
        dist = math.hypot(lead[0], lead[1])
        if dist > par.carrot_max:
            self._carrot[:2] = x[:2] + lead * (par.carrot_max / dist)
        self._carrot[2] = min(max(self._carrot[2], x[2] - par.carrot_max_v), x[2] + par.carrot_max_v)
        if grounded:
            self._carrot[:2] = x[:2]
            self._carrot[2] = min(max(self._carrot[2], -1.0), x[2] + 0.3)  # no run-away lead while spinning up

        # heading reference slews at the airframe's yaw-rate limit
        slew = par.max_yaw_rate * h
        turn = max(-slew, min(slew, wrap_deg(heading_cmd - self._heading_ref)))
        self._heading_ref = wrap_deg(self._heading_ref + turn)
        tail_trim = math.radians(turn / h) * par.heli.yaw_damping / par.heli.yaw_authority  # holds the turn rate
        psi = x[8]
        c, s = math.cos(psi), math.sin(psi)
        err = self._carrot - x[0:3]
        derr = v_ref - x[3:6]
        e_fwd, e_right = err[0] * c + err[1] * s, -err[0] * s + err[1] * c
        de_fwd, de_right = derr[0] * c + derr[1] * s, -derr[0] * s + derr[1] * c
        # trim attitude: what holds the reference velocity against the drag and gives its acceleration
        drag = par.heli.drag_h
        f_n, f_e = drag * v_ref[0] + a_ref[0], drag * v_ref[1] + a_ref[1]
        f_fwd, f_right = f_n * c + f_e * s, -f_n * s + f_e * c
        trim_pitch = -math.degrees(math.atan2(f_fwd, G))
        trim_roll = math.degrees(math.atan2(f_right, G))
        active = not grounded and st.rotor_rpm >= ROTOR_LIFT_RPM
        integrals = {axis: pid.integral for axis, pid in self.pids.items()}
        if active:
            pitch_ref = trim_pitch - self.pids[Axis.LONGITUDINAL].step(now, -e_fwd, sp=0.0, rate=de_fwd)
            roll_ref = trim_roll + self.pids[Axis.LATERAL].step(now, -e_right, sp=0.0, rate=de_right)
            yaw_err = wrap_deg(self._heading_ref - math.degrees(psi))
            tail = tail_trim + self.pids[Axis.YAW].step(now, -yaw_err, sp=0.0, rate=turn / h - math.degrees(x[11]))
            lat = self.pids[Axis.ROLL].step(now, math.degrees(x[6]), sp=roll_ref, rate=-math.degrees(x[9]))
            lon = self.pids[Axis.PITCH].step(now, math.degrees(x[7]), sp=pitch_ref, rate=-math.degrees(x[10]))
        else:
            for axis in (Axis.LONGITUDINAL, Axis.LATERAL, Axis.YAW, Axis.ROLL, Axis.PITCH):
                self.pids[axis].reset()
            tail = lat = lon = 0.0
        if st.rotor_rpm >= ROTOR_LIFT_RPM:
            if grounded:
                self.pids[Axis.ALTITUDE].reset()  # the skids carry the weight: nothing to integrate yet
            trim = par.heli.hover_collective * (par.heli.drag_v * v_ref[2] + a_ref[2]) / G  # climb against drag
            coll = trim + self.pids[Axis.ALTITUDE].step(now, x[2], sp=self._carrot[2], rate=derr[2])
            if rpm_ratio > 0:
                coll = min(coll / rpm_ratio ** 2, self.gains[Axis.ALTITUDE].sat_high)  # governor droop compensation
        else:
            self.pids[Axis.ALTITUDE].reset()
            coll = 0.0
        if grounded and not st.rotor_rpm >= ROTOR_LIFT_RPM:
            tail = 0.0

        wind = self._wind_step(h)
        z = np.concatenate([x, [lat, lon, tail, coll], [wind[0], wind[1], 0.0, rpm_ratio], [h]])
        nx = self._step_fn(z).full().ravel()

        # envelope protection: the protocol's speed guarantees
        floor = ENVELOPE_FLOOR
        self._speed_limit = min(par.max_speed, max(horiz, floor, self._speed_limit - par.max_accel * h))
        self._climb_limit = max(abs(cmd[2]), floor, self._climb_limit - par.max_vaccel * h)
        vh = math.hypot(nx[3], nx[4])
        if vh > self._speed_limit:
            nx[3:5] *= self._speed_limit / vh
            self._hold_integrals((Axis.LONGITUDINAL, Axis.LATERAL), integrals)  # conditional integration
        if abs(nx[5]) > self._climb_limit:
            nx[5] = math.copysign(self._climb_limit, nx[5])
            self._hold_integrals((Axis.ALTITUDE,), integrals)
        if nx[2] <= 0.0:  # ground contact: skids level, no sliding
            nx[2] = 0.0
            nx[3:6] = 0.0
            nx[6:8] = 0.0
            nx[9:11] = 0.0
            if st.rotor_rpm < ROTOR_LIFT_RPM:
                nx[11] = 0.0
        self._x = nx
        self._publish(h)

    def _hold_integrals(self, axes: tuple[Axis, ...], integrals: dict[Axis, float]) -> None:
        """The envelope clipped this axis's motion: what the loop integrated this step is not its own error."""
        for axis in axes:
            self.pids[axis].integral = integrals[axis]

    def _publish(self, h: float) -> None:
        st = self.state
        x = self._x
        st.pos = x[0:3].copy()
        st.vel = x[3:6].copy()
        roll, pitch = math.degrees(x[6]), math.degrees(x[7])
        x[8] = math.radians(wrap_deg(math.degrees(x[8])))
        st.roll, st.pitch, st.heading = roll, pitch, wrap_deg(math.degrees(x[8]))
        st.roll_rate, st.pitch_rate, st.yaw_rate = (math.degrees(v) for v in x[9:12])
        if st.rotor_rpm > 100.0:
            st.battery_v = max(0.0, st.battery_v - self.params.battery_drain * h)
