"""Mode 3: the path follower that runs in this module instead of the DSP (seed 004 §5.3.2.3).

The whole DATOS trajectory is flown from here: every telemetry frame (the control period) the aircraft is
projected on the current segment, the deviation across the path and in height goes through an LQR gain
computed for that segment (casadi linearisation of :func:`control.heli.guided_model` at the segment's
operating point, discrete Riccati equation) plus a seed-002 integral with its anti-windup, and the resulting
velocity command (``ω = sp_ω + ω_prop + ω_int``: along-path speed + LQR + integral) goes to the DSP as
bridge references (``SET_REFS``: a target offset the DSP's bridge law turns back into that velocity,
docs/dsp_protocol.md). HEADING and VELOCIDAD are honoured as in modes 0/1: facing the path unless a HEADING
was given, at the last VELOCIDAD. No bus, no clock of its own: :meth:`OnboardFollower.step` takes the time.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from bbcs.contracts import dsp as p
from bbcs.contracts.error_codes import FollowerError
from bbcs.geodesy import local_en
from control.heli import GuidedParams, guided_model, guided_params
from control.laws import AntiWindup, integral_action, integrate_scalar, total_action
from modules.path_follower.logic import Decision, FollowerState

BRIDGE_GAIN = 0.8  # 1/s: the DSP's bridge law, speed = min(v_max, √(2·a·d), k·d) toward the REFS target
BRIDGE_BRAKE = 1.5  # m/s²
NOMINAL_RPM = 1500.0


@dataclass(frozen=True)
class OnboardParams:
    period_s: float = 0.05  # the control period the gains are designed for (the telemetry period)
    q_pos: float = 1.0  # LQR weights: position deviation, velocity deviation, command
    q_vel: float = 0.3
    r: float = 0.6
    k_int: float = 0.08  # 1/s²: integral gain on cross-track and height error
    aw: AntiWindup = AntiWindup(th_dist=4.0, th_max=1.0, accum_high=15.0, accum_low=-15.0)
    corner_speed: float = 1.5  # m/s, speed through a corner
    corner_accel: float = 1.0  # m/s², deceleration planned before a corner
    switch_m: float = 1.0  # m before a segment's end the next segment takes over
    final_m: float = 3.0  # m before the trajectory's end: one reference at the end point, then the DSP holds it
    max_deviation_m: float = 30.0
    max_speed: float = 10.0
    max_climb: float = 2.0
    guided: GuidedParams | None = None  # None: derived from control.heli's airframe and the DSP gains


@dataclass(frozen=True)
class Segment:
    start: np.ndarray  # local n, e, u
    end: np.ndarray
    tangent: np.ndarray  # unit, 3-D
    normal: np.ndarray  # unit, horizontal, to the right of the tangent
    binormal: np.ndarray  # unit, ⟂ both, mostly up
    length: float
    gain: np.ndarray  # LQR K (2×4) on [e_n, e_b, ė_n, ė_b]


@dataclass(frozen=True)
class StepResult:
    commands: tuple[p.Command, ...] = ()
    errors: tuple[int, ...] = ()
    detail: str = ""
    solve_s: float = 0.0  # wall time spent computing this step
    solve_cpu_s: float = 0.0  # CPU time of this thread for it (what the step costs, without preemption)


def _frame(tangent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    h = math.hypot(tangent[0], tangent[1])
    normal = np.array([-tangent[1], tangent[0], 0.0]) / h if h > 1e-6 else np.array([0.0, 1.0, 0.0])
    binormal = np.cross(normal, tangent)
    if binormal[2] < 0:
        binormal = -binormal
    return normal, binormal


def bridge_offset(speed: float) -> float:
    """The target distance at which the DSP's bridge law flies at ``speed`` (inverse of its speed law)."""
    return max(speed / BRIDGE_GAIN, speed * speed / (2.0 * BRIDGE_BRAKE))


class OnboardFollower:
    """Trajectory, segment, integrators and gains of mode 3."""

    def __init__(self, params: OnboardParams | None = None) -> None:
        self.params = params or OnboardParams()
        self.guided = self.params.guided or guided_params()
        self.model: Any = None  # the casadi model, built with the first trajectory (mode 3 only needs casadi)
        self.speed = 0.0
        self.heading_rad: float | None = None
        self.reset()

    # --- inputs -----------------------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget the trajectory (abort, mode change): the next step holds nothing and sends nothing."""
        self.points: tuple[tuple[float, float, float], ...] = ()
        self.segments: list[Segment] = []
        self.index = 0
        self.integral = np.zeros(2)
        self.origin: tuple[float, float, float] | None = None
        self.complete = False
        self._last_t: float | None = None
        self._nav_reported = False

    def set_speed(self, speed: float) -> None:
        self.speed = max(0.0, min(speed, self.params.max_speed))

    def set_heading(self, heading_rad: float | None) -> None:
        """A HEADING datum: face it while following (None: face along the path, as mode 0)."""
        self.heading_rad = heading_rad

    def set_points(self, points: Sequence[tuple[float, float, float]]) -> None:
        """The onboard trajectory (lat, lon, alt MSL): a longer trajectory with the same beginning extends the
        one being flown (a second DATOS appends, as the DSP queue does); anything else replaces it."""
        points = tuple((float(a), float(b), float(c)) for a, b, c in points)
        if points == self.points:
            return
        if not points:
            self.reset()
            return
        if self.points and points[: len(self.points)] == self.points:
            self.points = points
            if self.segments:  # otherwise the first step builds them all, from where the aircraft is
                self._extend()
            self.complete = False
            return
        self.reset()
        self.points = points

    # --- geometry ---------------------------------------------------------------------------------------

    def to_local(self, lat: float, lon: float, alt: float) -> np.ndarray:
        assert self.origin is not None
        lat0, lon0, alt0 = self.origin
        east, north = local_en(lat0, lon0, lat, lon)
        return np.array([north, east, alt - alt0])

    def _extend(self, start: np.ndarray | None = None) -> None:
        """Segments (with their LQR gains) for every point not yet in one."""
        locals_ = [self.to_local(*pt) for pt in self.points]
        if start is None:
            start = self.segments[-1].end if self.segments else locals_[0]
        first_new = len(self.segments)  # segment k ends at point k
        ops = []
        geo = []
        prev = start if first_new == 0 else self.segments[-1].end
        for end in locals_[first_new:]:
            d = end - prev
            length = float(np.linalg.norm(d))
            tangent = d / length if length > 1e-6 else np.array([0.0, 0.0, 1.0])
            normal, binormal = _frame(tangent)
            v0 = tangent * self.speed
            ops.append((np.concatenate([prev, v0]), v0))
            geo.append((prev, end, tangent, normal, binormal, length))
            prev = end
        from control.linearize import linearize_along  # casadi + scipy: imported by mode 3 only, not at start-up

        self.model = self.model or guided_model(self.guided)
        for (a, b), (s, e, t, n, bn, length) in zip(linearize_along(self.model, ops), geo, strict=True):
            self.segments.append(Segment(s, e, t, n, bn, length, self._gain(a, b, n, bn)))

    def _gain(self, a: np.ndarray, b: np.ndarray, normal: np.ndarray, binormal: np.ndarray) -> np.ndarray:
        """LQR gain of the deviation across the segment: the model's (A, B) seen in the segment's frame."""
        proj = np.vstack([normal, binormal])  # 2×3
        a_vv = proj @ a[3:6, 3:6] @ proj.T
        b_v = proj @ b[3:6, :] @ proj.T
        az = np.block([[np.zeros((2, 2)), np.eye(2)], [np.zeros((2, 2)), a_vv]])
        bz = np.vstack([np.zeros((2, 2)), b_v])
        from control.linearize import discretize
        from control.lqr import dlqr

        ad, bd = discretize(az, bz, self.params.period_s)
        par = self.params
        k, _ = dlqr(ad, bd, np.diag([par.q_pos, par.q_pos, par.q_vel, par.q_vel]), np.eye(2) * par.r)
        return k

    # --- the control step -------------------------------------------------------------------------------

    def step(self, now: float, telemetry: p.Telemetry) -> StepResult:
        """One control period: the REFS to send for this telemetry frame (nothing without a trajectory)."""
        if not self.points or self.complete:  # complete: the DSP holds the end point; nothing more to send
            return StepResult()
        t0, c0 = time.perf_counter(), time.thread_time()
        pos_msg, vel_msg = telemetry.position, telemetry.velocity
        heading = telemetry.heading if telemetry.heading is not None else (
            telemetry.attitude.yaw if telemetry.attitude is not None else None)
        if pos_msg is None or vel_msg is None or heading is None:
            if self._nav_reported:
                return StepResult()
            self._nav_reported = True
            return StepResult(errors=(int(FollowerError.NO_NAVIGATION),),
                              detail="mode 3 needs position, velocity and heading in the DSP telemetry")
        if self.origin is None:
            self.origin = (pos_msg.lat, pos_msg.lon, pos_msg.alt)
        pos = self.to_local(pos_msg.lat, pos_msg.lon, pos_msg.alt)
        vel = np.array([vel_msg.vn, vel_msg.ve, -vel_msg.vd])
        if not self.segments:
            self._extend(start=pos)
        ts = None if self._last_t is None else now - self._last_t
        self._last_t = now
        par = self.params

        seg = self.segments[self.index]
        while True:  # advance past segments whose end is (about) reached
            s = float((pos - seg.start) @ seg.tangent)
            if s < seg.length - par.switch_m or self.index == len(self.segments) - 1:
                break
            self.index += 1
            seg = self.segments[self.index]
        last = self.index == len(self.segments) - 1
        s = min(max(s, 0.0), seg.length)
        dev = pos - (seg.start + seg.tangent * s)
        z = np.array([dev @ seg.normal, dev @ seg.binormal, vel @ seg.normal, vel @ seg.binormal])
        if math.hypot(z[0], z[1]) > par.max_deviation_m:
            self.reset()
            return StepResult((p.Abort(),), (int(FollowerError.OFF_PATH),),
                              f"{math.hypot(z[0], z[1]):.1f} m off the trajectory (limit "
                              f"{par.max_deviation_m} m): trajectory dropped, DSP holding",
                              time.perf_counter() - t0, time.thread_time() - c0)

        to_go = seg.length - s
        if last and to_go <= par.final_m:
            self.complete = True
            return StepResult((self._end_refs(pos, pos_msg.alt, heading, seg),),
                              detail="trajectory complete: the DSP holds its end point",
                              solve_s=time.perf_counter() - t0, solve_cpu_s=time.thread_time() - c0)
        end_speed = 0.0 if last else min(par.corner_speed, self.speed)
        v_along = min(self.speed, math.sqrt(end_speed ** 2 + 2.0 * par.corner_accel * to_go))
        if ts is not None and ts > 0:
            aw = par.aw
            self.integral = np.array([integrate_scalar(self.integral[i], -z[i], ts, aw.th_dist, aw.th_max,
                                                       aw.low(), aw.accum_high) for i in (0, 1)])
        feed = seg.tangent * v_along  # sp_ω: the along-path velocity
        prop = -seg.gain @ z  # ω_prop = K (sp − x) with sp = 0 on the path
        corr = total_action(np.zeros(2), prop, integral_action(par.k_int, self.integral))
        u = feed + seg.normal * corr[0] + seg.binormal * corr[1]
        result = self._refs(u, pos_msg.alt, heading, seg)
        return StepResult((result,), solve_s=time.perf_counter() - t0, solve_cpu_s=time.thread_time() - c0)

    def _end_refs(self, pos: np.ndarray, alt_msl: float, heading_deg: float, seg: Segment) -> p.SetRefs:
        """The last reference: the trajectory's end point itself. The DSP's bridge law brakes onto a SET_REFS
        target and holds it (docs/dsp_protocol.md), so after this one the aircraft is flown to the end and kept
        there with nothing more sent: when the task ends, no command of it follows."""
        d = seg.end - pos
        psi = math.radians(heading_deg)
        ref_heading = self._heading_ref(heading_deg, seg)
        return p.SetRefs(ref_altura=float(alt_msl + d[2]),
                         error_longitudinal=float(d[0] * math.cos(psi) + d[1] * math.sin(psi)),
                         error_lateral=float(-d[0] * math.sin(psi) + d[1] * math.cos(psi)),
                         ref_heading=float(ref_heading), ref_rpm_motor=NOMINAL_RPM)

    def _heading_ref(self, heading_deg: float, seg: Segment) -> float:
        """The HEADING datum if one was given, else along the segment (level flight), else the current heading."""
        if self.heading_rad is not None:
            ref = self.heading_rad
        elif math.hypot(seg.tangent[0], seg.tangent[1]) > 0.1:
            ref = math.atan2(seg.tangent[1], seg.tangent[0])
        else:
            ref = math.radians(heading_deg)
        return (ref + math.pi) % (2 * math.pi) - math.pi

    def _refs(self, u: np.ndarray, alt_msl: float, heading_deg: float, seg: Segment) -> p.SetRefs:
        """Velocity command → the bridge references that make the DSP fly it."""
        par = self.params
        vh = min(math.hypot(u[0], u[1]), par.max_speed)
        dist = bridge_offset(vh)
        course = math.atan2(u[1], u[0])
        rel = course - math.radians(heading_deg)
        climb = min(max(u[2], -par.max_climb), par.max_climb)
        ref_heading = self._heading_ref(heading_deg, seg)
        return p.SetRefs(ref_altura=float(alt_msl + climb / BRIDGE_GAIN),
                         error_longitudinal=float(dist * math.cos(rel)),
                         error_lateral=float(dist * math.sin(rel)), ref_heading=float(ref_heading),
                         ref_rpm_motor=NOMINAL_RPM)  # plain floats: the bus codec does not take numpy scalars


def decide(follower: OnboardFollower, state: FollowerState, telemetry: p.Telemetry) -> Decision:
    """Mode 3's answer to one DSP telemetry frame: the onboard trajectory (``state.path``) flown one period.

    The clock is the DSP's own (``time_ms``), so the integral's sampling period is what passed between frames.
    Outside mode 3 the follower forgets its trajectory and sends nothing.
    """
    if state.mode != p.Mode.ONBOARD_FOLLOWER:
        if follower.points:
            follower.reset()
        return Decision(state)
    follower.set_points([(pt.latitud, pt.longitud, pt.altura) for pt in state.path])
    result = follower.step(telemetry.time_ms / 1000.0, telemetry)
    if follower.complete or FollowerError.OFF_PATH in result.errors:
        # flown (the DSP holds the end point) or dropped (the DSP holds here): the trajectory is forgotten, so
        # nothing more is sent for it, and a later DATOS is a new trajectory from where the aircraft is
        follower.reset()
        return Decision(replace(state, path=()), result.commands, result.errors, result.detail)
    return Decision(state, result.commands, result.errors, result.detail)
