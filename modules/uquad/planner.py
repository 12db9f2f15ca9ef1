"""The path planner (seed 002 §1.2.6): set points from the current task; completion detection.

Pure state machine, injected time. Task modes (the manifest's ``uquad_mode`` slot): IDLE (on the ground, motors
off), HOLD (stay where the set point is), GOTO (fly the waypoints the RAL put on the path slot), TAKE_OFF
(climb the task's height, else TAKEOFF_HEIGHT_DEFAULT, above the take-off point), LAND (descend at LAND_SPEED,
motors off once on the ground),
ABORT (stop where the quadrotor is now: the set point starts at the estimated position and velocity, brakes to a
halt and holds there), MANUAL
(the seed's manual mode: hover, each manual command moves the hover target by an offset; :meth:`Planner.manual`).

A task's parameters (the RAL's task slot) arrive apart from its mode: the take-off height and the goto speed
are kept (:meth:`Planner.set_takeoff_height`, :meth:`Planner.set_speed`) and used from then on, whichever of
the two arrived first; without them the .conf's TAKEOFF_HEIGHT_DEFAULT and CRUISE_SPEED apply.

Completion (the seed's flag to the controller): a waypoint is reached when the estimate is within
WAYPOINT_RADIUS of it and slower than WAYPOINT_SPEED_MAX; then the next one becomes the target and
``new_target`` is raised (the set-point controller relinearises). Take-off completes at the target height
(then HOLD); landing when below GROUND_HEIGHT above the take-off point and still for ``still_s`` (then IDLE).
The set point moves toward the target no faster than CRUISE_SPEED (a carrot), so the errors stay small, and its
velocity changes no faster than SETPOINT_ACCEL: it speeds up, slows down to arrive, turns and stops smoothly. A
set-point velocity that jumped (a hold or an abort at cruise speed, a goto the other way) made the law tilt the
quadrotor 45 degrees, and 88 degrees for a reversal (tumbling: the motors cut).
"""

from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from bbcs.contracts.tasks import FollowPath, Goto, Manual, TakeOff, TaskParams
from modules.uquad import model


class Mode(enum.IntEnum):
    HOLD = 0
    GOTO = 1
    TAKE_OFF = 2
    LAND = 3
    ABORT = 4
    IDLE = 5
    MANUAL = 6


@dataclass(frozen=True)
class PlannerConfig:
    takeoff_height: float = 3.0
    waypoint_radius: float = 0.5
    waypoint_speed_max: float = 0.5
    cruise_speed: float = 2.0
    climb_speed: float = 1.0
    land_speed: float = 0.5
    ground_height: float = 0.15
    still_s: float = 0.5
    max_height: float = 20.0
    """Metres above the take-off point that no take-off or manual target may exceed."""
    accel: float = 2.0
    """m/s²: the set point's velocity changes no faster (about 11 degrees of tilt to follow it)."""


@dataclass
class PlanOutput:
    position: np.ndarray
    velocity: np.ndarray
    yaw: float
    motors_on: bool
    new_target: bool


@dataclass
class Planner:
    cfg: PlannerConfig = field(default_factory=PlannerConfig)
    mode: Mode = Mode.IDLE
    ground_z: float = 0.0
    sp: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw: float = 0.0
    waypoints: deque[np.ndarray] = field(default_factory=deque)
    takeoff_height: float | None = None
    """The running take-off task's height above the take-off point (None: the .conf's default)."""
    speed: float | None = None
    """The running goto's speed (None: the .conf's cruise speed)."""
    manual_target: np.ndarray | None = None
    sp_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """The set point's velocity: continuous, changed by at most ``accel`` per second."""
    _still_since: float | None = None
    _flag: bool = False
    completed: list[str] = field(default_factory=list)
    """What finished, in order ('take_off', 'waypoint', 'goto', 'land'), for logs and tests."""

    @property
    def airborne(self) -> bool:
        return self.mode is not Mode.IDLE

    def set_mode(self, mode: Mode, position: np.ndarray, yaw: float, velocity: np.ndarray | None = None) -> None:
        """A new task mode; ``position``/``yaw``/``velocity`` are the current estimate (an abort brakes from that
        position and velocity; without a velocity, from the set point's own)."""
        if mode is Mode.IDLE:
            self.mode = Mode.IDLE
            return
        if self.mode is Mode.IDLE:  # leaving the ground: everything relative to here
            if mode in (Mode.LAND, Mode.HOLD, Mode.ABORT, Mode.MANUAL):
                return  # nothing to land or hold on the ground
            self.ground_z = float(position[2])
            self.sp = np.array(position, dtype=float)
            self.sp_velocity = np.zeros(3)
            self.yaw = yaw
        if mode is Mode.ABORT:
            self.sp = np.array(position, dtype=float)
            if velocity is not None:
                self.sp_velocity = np.array(velocity, dtype=float)
            self.waypoints.clear()
        if mode is not Mode.GOTO:
            self.waypoints.clear()
        if mode is Mode.MANUAL and self.mode is not Mode.MANUAL:
            self.manual_target = self.sp.copy()  # hover where the set point is until the first command
        self.mode = mode
        self._still_since = None
        self._flag = True

    def set_takeoff_height(self, height: float) -> str:
        """The take-off task's height; returns why it is refused ("" when taken)."""
        if not 0.0 < height <= self.cfg.max_height:
            return f"take-off height {height:g} m outside (0, {self.cfg.max_height:g}] m"
        self.takeoff_height = float(height)
        return ""

    def set_speed(self, speed: float) -> str:
        if not 0.0 < speed:
            return f"speed {speed:g} m/s must be positive"
        self.speed = float(speed)
        return ""

    def manual(self, east: float, north: float, up: float, yaw_deg: float) -> str:
        """A manual command: move the hover target (and the yaw) by these offsets. Refused (nothing changes, the
        reason returned) when not flying or when the target would leave [GROUND_HEIGHT, max_height] above the
        take-off point."""
        if self.mode is Mode.IDLE:
            return "manual command on the ground: take off first"
        base = self.manual_target if self.mode is Mode.MANUAL and self.manual_target is not None else self.sp
        target = base + np.array([east, north, up], dtype=float)
        height = float(target[2]) - self.ground_z
        if not self.cfg.ground_height < height <= self.cfg.max_height:
            return (f"manual target {height:.2f} m above the take-off point is outside "
                    f"({self.cfg.ground_height:g}, {self.cfg.max_height:g}] m")
        self.mode = Mode.MANUAL
        self.waypoints.clear()
        self.manual_target = target
        self.yaw = math.remainder(self.yaw + math.radians(yaw_deg), math.tau)
        self._flag = True
        return ""

    def set_waypoints(self, points: list[np.ndarray]) -> None:
        self.waypoints = deque(np.array(p, dtype=float) for p in points)
        self._flag = True

    def step(self, now: float, dt: float, position: np.ndarray, velocity: np.ndarray) -> PlanOutput:
        c = self.cfg
        target: np.ndarray | None = None
        speed = self.speed or c.cruise_speed
        if self.mode is Mode.TAKE_OFF:
            height = self.takeoff_height if self.takeoff_height is not None else c.takeoff_height
            target = np.array([self.sp[0], self.sp[1], self.ground_z + height])
            speed = c.climb_speed
            if self._reached(target, position, velocity):
                self.completed.append("take_off")
                self.mode = Mode.HOLD
                self._flag = True
        elif self.mode is Mode.MANUAL:
            target = self.manual_target
            speed = c.cruise_speed
        elif self.mode is Mode.GOTO:
            if self.waypoints:
                target = self.waypoints[0]
                if self._reached(target, position, velocity):
                    self.waypoints.popleft()
                    self.completed.append("waypoint")
                    self._flag = True
                    target = self.waypoints[0] if self.waypoints else None
                    if target is None:
                        self.completed.append("goto")
                        self.mode = Mode.HOLD
        elif self.mode is Mode.LAND:
            target = np.array([self.sp[0], self.sp[1], self.ground_z - 1.0])
            speed = c.land_speed
            low = position[2] - self.ground_z < c.ground_height
            if low and abs(velocity[2]) < 0.2:
                self._still_since = now if self._still_since is None else self._still_since
                if now - self._still_since >= c.still_s:
                    self.completed.append("land")
                    self.mode = Mode.IDLE
            else:
                self._still_since = None
        self._move(target, speed, dt)
        flag, self._flag = self._flag, False
        return PlanOutput(self.sp.copy(), self.sp_velocity.copy(), self.yaw, self.mode is not Mode.IDLE, flag)

    def _move(self, target: np.ndarray | None, speed: float, dt: float) -> None:
        """The carrot: toward ``target`` at up to ``speed``, slowing to arrive on it (v ≤ √(2·a·distance)), or to a
        halt without one; its velocity changes by at most ``accel``·dt a step. A step that would reach the target
        ends on it, at rest."""
        a = self.cfg.accel
        wanted = np.zeros(3)
        delta = np.zeros(3) if target is None else target - self.sp
        dist = float(np.linalg.norm(delta))
        if target is not None and dist > 1e-9:
            half = a * dt / 2.0  # √(2·a·d) for steps of dt: the speed it can still brake from, a·dt a step
            wanted = delta / dist * min(speed, math.sqrt(half * half + 2.0 * a * dist) - half)
        change = wanted - self.sp_velocity
        size = float(np.linalg.norm(change))
        if size > a * dt:
            change *= a * dt / size
        self.sp_velocity = self.sp_velocity + change
        step = self.sp_velocity * dt
        if target is not None and (dist <= 1e-9 or (dist <= float(np.linalg.norm(step))
                                                     and float(np.dot(step, delta)) > 0.0)):
            self.sp = np.array(target, dtype=float)
            self.sp_velocity = np.zeros(3)
        else:
            self.sp = self.sp + step

    def _reached(self, target: np.ndarray, position: np.ndarray, velocity: np.ndarray) -> bool:
        return (float(np.linalg.norm(target - position)) <= self.cfg.waypoint_radius
                and float(np.linalg.norm(velocity)) <= self.cfg.waypoint_speed_max
                and float(np.linalg.norm(target - self.sp)) < 1e-6)

    def setpoint_state(self, out: PlanOutput) -> np.ndarray:
        """The 12-state set point for the controller (model order)."""
        s = np.zeros(model.N_STATES)
        s[model.IX:model.IZ + 1] = out.position
        s[model.IVX:model.IVZ + 1] = out.velocity
        s[model.ITHETA] = out.yaw
        return s


def apply_task(planner: Planner, params: TaskParams) -> str:
    """A started task's parameters into the planner: why they were refused, or "" (other kinds carry none)."""
    if isinstance(params, TakeOff):
        return planner.set_takeoff_height(params.height)
    if isinstance(params, Goto | FollowPath) and params.speed is not None:
        return planner.set_speed(params.speed)
    if isinstance(params, Manual):
        return planner.manual(params.east, params.north, params.up, params.yaw)
    return ""


def heading_deg(theta: float) -> float:
    """Seed yaw (0 = world x = east, counter-clockwise) → compass heading (0 = north, clockwise)."""
    return (90.0 - math.degrees(theta)) % 360.0
