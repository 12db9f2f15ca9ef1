"""A helicopter as a point mass with rate and acceleration limits, integrated with an injected time step.

Good enough to make path following, heading hold, take-off and landing move plausibly, and small enough to
reason about in tests: velocity follows the commanded velocity through a first-order lag with bounded
acceleration, heading turns toward its reference at a bounded rate, the ground stops the descent, and the
rotor must be up to speed before the aircraft leaves the ground. Attitude is derived from the acceleration
(a helicopter tilts its rotor disc to accelerate). Local frame: north, east, up (metres from the home point).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

G = 9.80665
ROTOR_FLIGHT_RPM = 1500.0
ROTOR_LIFT_RPM = 1200.0  # below this the aircraft cannot leave the ground


def wrap_deg(angle: float) -> float:
    """Angle in degrees wrapped into [-180, 180)."""
    wrapped = (angle + 180.0) % 360.0 - 180.0
    return wrapped - 360.0 if wrapped >= 180.0 else wrapped


@dataclass(frozen=True)
class VehicleParams:
    max_speed: float = 10.0  # m/s, airframe horizontal limit (the DSP's MAX_SPEED)
    max_climb: float = 2.0  # m/s
    max_accel: float = 2.5  # m/s², horizontal
    max_vaccel: float = 2.0  # m/s², vertical
    velocity_gain: float = 1.5  # 1/s, velocity loop bandwidth
    max_yaw_rate: float = 60.0  # deg/s
    yaw_gain: float = 2.0  # 1/s
    rotor_tau: float = 1.0  # s, rotor speed time constant
    battery_full: float = 25.2  # V (6S LiPo for the avionics)
    battery_drain: float = 0.002  # V/s while the rotor turns


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


class Vehicle:
    """Integrates VehicleState; ``step`` is pure apart from the state it owns (no clock, no I/O)."""

    def __init__(self, params: VehicleParams | None = None, state: VehicleState | None = None) -> None:
        self.params = params or VehicleParams()
        self.state = state or VehicleState(battery_v=self.params.battery_full)

    def step(self, dt: float, v_cmd: np.ndarray, heading_cmd: float, rpm_cmd: float) -> None:
        """Advance ``dt`` seconds toward commanded velocity (n, e, up), heading (deg) and rotor speed."""
        if dt <= 0:
            raise ValueError("dt must be positive")
        par = self.params
        st = self.state
        cmd = np.array(v_cmd, dtype=float)
        horiz = math.hypot(cmd[0], cmd[1])
        if horiz > par.max_speed:
            cmd[:2] *= par.max_speed / horiz
        cmd[2] = min(max(cmd[2], -par.max_climb), par.max_climb)

        st.rotor_rpm += (rpm_cmd - st.rotor_rpm) * min(1.0, dt / par.rotor_tau)
        grounded = st.pos[2] <= 0.0
        if grounded and st.rotor_rpm < ROTOR_LIFT_RPM:
            cmd[:] = 0.0  # no lift: the skids stay on the ground
        elif grounded:
            cmd[:2] = 0.0  # lift off vertically; no sliding along the ground

        acc = par.velocity_gain * (cmd - st.vel)
        a_h = math.hypot(acc[0], acc[1])
        if a_h > par.max_accel:
            acc[:2] *= par.max_accel / a_h
        acc[2] = min(max(acc[2], -par.max_vaccel), par.max_vaccel)
        st.vel = st.vel + acc * dt
        st.pos = st.pos + st.vel * dt
        if st.pos[2] <= 0.0:  # ground contact
            st.pos[2] = 0.0
            st.vel[2] = max(st.vel[2], 0.0)
            if st.vel[2] == 0.0:
                st.vel[:2] = 0.0
                acc[:] = 0.0
        st.accel = acc

        err = wrap_deg(heading_cmd - st.heading)
        rate = min(max(par.yaw_gain * err, -par.max_yaw_rate), par.max_yaw_rate)
        if not st.airborne and st.rotor_rpm < ROTOR_LIFT_RPM:
            rate = 0.0
        st.yaw_rate = rate
        st.heading = wrap_deg(st.heading + rate * dt)

        psi = math.radians(st.heading)
        a_fwd = acc[0] * math.cos(psi) + acc[1] * math.sin(psi)
        a_right = -acc[0] * math.sin(psi) + acc[1] * math.cos(psi)
        pitch = -math.degrees(math.atan2(a_fwd, G))  # nose down to accelerate forward
        roll = math.degrees(math.atan2(a_right, G))
        st.pitch_rate, st.roll_rate = (pitch - st.pitch) / dt, (roll - st.roll) / dt
        st.pitch, st.roll = pitch, roll
        if st.rotor_rpm > 100.0:
            st.battery_v = max(0.0, st.battery_v - par.battery_drain * dt)
