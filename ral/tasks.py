"""What the RAL decides about tasks, with no bus and no clock of its own (every call takes ``now``).

- :func:`admit`: a GRI task against what the robot offers, where it is and its .conf limits (:class:`Limits`):
  speed (the task's, else the cruise speed; never above MAX_SPEED), clearance above the take-off point,
  geofence, ceiling, take-off height. A refusal says why; nothing is sent.
- :func:`return_request`, :func:`after_completed`: the ``return`` failsafe (RETURN_HEIGHT, RETURN_ACTION).
- :func:`judge`: one running task (as the Module Manager's task book lists it) against new telemetry: completed,
  failed (no progress for ``stall_s``: the distance still to fly along its path did not shrink), or still running.
  Its per-task memory is a :class:`Progress`.

The RAL keeps no task book: the Module Manager's is the only record of the running task of each type.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Annotated, Literal

import msgspec

from bbcs import ConfDocument, ConfError, load_conf
from bbcs.contracts import tasks as t
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.geodesy import distance_m, local_en, valid_lat_lon

HEADING_TASK = "follow_path_heading"
"""The manifest task a follow_path with a heading runs (path mode 1, HEADING routed to the RAL)."""
ONBOARD_TASK = "follow_path_onboard"
"""The manifest task a follow_path with ``follower = "onboard"`` runs (path mode 3, with or without a heading)."""
MIN_PROGRESS_M = 0.5
"""Movement smaller than this (towards the target, or in altitude) is not progress."""


@dataclass(frozen=True)
class Geofence:
    """A circle: centre (WGS84 degrees) and radius in metres."""

    lat: float
    lon: float
    radius_m: float


@dataclass(frozen=True)
class Limits:
    """What the robot's .conf allows (docs/gcs.md): speeds in m/s, heights in metres above the take-off point."""

    max_speed: float
    cruise_speed: float | None = None
    min_clearance_m: float | None = None
    max_height_m: float | None = None
    geofence: Geofence | None = None
    takeoff_height_m: float | None = None
    """The height the DSP climbs to in take-off mode (it takes no other)."""
    return_height_m: float | None = None
    """``RETURN_HEIGHT``: a ``return`` flies home this high above the take-off point (None: at the height it has,
    never under the minimum clearance)."""
    return_action: str = "land"
    """``RETURN_ACTION``: what a ``return`` does once home, ``land`` or ``hover``."""


@dataclass(frozen=True)
class JudgeConfig:
    position_tolerance_m: float = 3.0
    altitude_tolerance_m: float = 2.0
    settle_s: float = 2.0
    """Without the waypoint queue seen non-empty, a path task may complete only after this."""
    stall_s: float = 30.0
    """A movement task that makes no progress for this long fails."""
    max_range_m: float = 20_000.0
    arrival_speed_mps: float = 1.0
    """A path task completes only once the robot is this slow (horizontal and vertical, when its telemetry has a
    velocity): at its goal, not passing by it. The onboard follower's empty queue says nothing, and within the
    position tolerance the robot may still be flying the last metres under its commands."""


@dataclass(frozen=True)
class Rejected:
    reason: str


@dataclass(frozen=True)
class Plan:
    """An admitted task: the manifest task to start and its parameters (speed filled in)."""

    kind: str
    name: str
    task_type: str
    params: t.TaskParams


def available_kinds(available: dict[str, str], task_names: dict[str, str]) -> dict[str, str]:
    """GRI kind → task type: only the kinds a ground station can send that the manifest maps."""
    out = {}
    for kind in t.TASK_KINDS:
        task_type = available.get(task_names.get(kind, kind))
        if task_type is not None:
            out[kind] = task_type
    return out


PATH_TASKS = (t.Goto, t.FollowPath, t.FollowVisionPath, t.Bridge, t.Survey, t.Orbit)
"""Tasks that fly the robot somewhere: refused while it is on the ground (a take-off comes first)."""


def admit(request: t.TaskParams, *, available: dict[str, str], task_names: dict[str, str], limits: Limits,
          cfg: JudgeConfig, telemetry: RobotTelemetry | None, home: GeoPoint | None) -> Plan | Rejected:
    """Check a decoded task against the robot; nothing changes here."""
    kind = t.kind_of(request)
    name = task_names.get(kind, kind)
    if isinstance(request, t.FollowPath) and request.heading is not None:
        name = task_names.get(HEADING_TASK, HEADING_TASK)
    if isinstance(request, t.FollowPath) and request.follower == "onboard":
        name = task_names.get(ONBOARD_TASK, ONBOARD_TASK)
    if not available:
        return Rejected("the robot's task list is unknown (Module Manager not answering)")
    task_type = available.get(name)
    if task_type is None and name == task_names.get(ONBOARD_TASK, ONBOARD_TASK):
        return Rejected(f"follow_path with the onboard follower: this robot has no {ONBOARD_TASK!r} task "
                        "(path mode 3)")
    if task_type is None and name == task_names.get(HEADING_TASK, HEADING_TASK):
        return Rejected(f"follow_path with a heading: this robot has no {HEADING_TASK!r} task (path mode 1)")
    if task_type is None:
        offered = ", ".join(sorted(available_kinds(available, task_names))) or "none"
        return Rejected(f"this robot has no task {kind!r} (it offers: {offered})")
    params: t.TaskParams = request
    speed = getattr(request, "speed", "absent")
    if speed != "absent":
        if speed is None:
            if limits.cruise_speed is None:
                return Rejected(f"{kind}: no speed given and the robot's .conf has no CRUISE_SPEED")
            params = msgspec.structs.replace(request, speed=limits.cruise_speed)  # type: ignore[type-var]
        elif not speed > 0:
            return Rejected(f"{kind}: speed {speed:g} m/s: a task is flown at a positive speed (none given: the "
                            "robot's CRUISE_SPEED)")
        elif speed > limits.max_speed:
            return Rejected(f"{kind}: speed {speed:g} m/s is above MAX_SPEED {limits.max_speed:g} m/s")
    if isinstance(request, t.TakeOff) and limits.takeoff_height_m is not None:
        if abs(request.height - limits.takeoff_height_m) > cfg.altitude_tolerance_m:
            return Rejected(f"take_off: the DSP climbs to its fixed take-off height {limits.takeoff_height_m:g} m "
                            f"above home; {request.height:g} m cannot be honoured")
    if isinstance(request, t.TakeOff) and limits.max_height_m is not None and request.height > limits.max_height_m:
        return Rejected(f"take_off: height {request.height:g} m is above the ceiling {limits.max_height_m:g} m")
    if isinstance(request, t.Manual):
        why = _manual_step(request, limits, telemetry, home)
        if why:
            return Rejected(f"manual: {why}")
    if isinstance(request, t.Survey | t.Orbit):
        why = _generated_area(request, limits, cfg, telemetry)
        if why:
            return Rejected(f"{kind}: {why}")
    points = _points(request)
    if points:
        why = _check_points(points, limits, cfg, telemetry, home)
        if why:
            return Rejected(f"{kind}: {why}")
    if isinstance(request, PATH_TASKS) and telemetry is not None and telemetry.airborne is False:
        # last, so a request's own faults are named first (they hold in the air too). A path flown from the ground
        # climbs along it, low over the ground for its whole first leg, through the minimum clearance with no
        # take-off behind it (the safety monitor's below_clearance, found by the campaign)
        return Rejected(f"{kind}: the robot is on the ground (take off first)")
    return Plan(kind, name, task_type, params)


def _points(request: t.TaskParams) -> list[tuple[str, float, float, float | None]]:
    """(label, lat, lon, alt above sea level or None) of every place a task sends the robot to."""
    if isinstance(request, t.Goto | t.FollowPath):
        return [(f"waypoint {i}", w.lat, w.lon, w.alt) for i, w in enumerate(request.waypoints)]
    if isinstance(request, t.Bridge):
        return [("ref_altitude", math.nan, math.nan, request.ref_altitude)]
    return []


def _manual_step(request: t.Manual, limits: Limits, telemetry: RobotTelemetry | None,
                 home: GeoPoint | None) -> str:
    """A manual step needs an airborne robot and must keep it between the ground and the ceiling: why not, or ""."""
    if telemetry is None or telemetry.position is None or home is None:
        return "the robot's position or take-off point is not known yet"
    if not telemetry.airborne:
        return "the robot is on the ground (take off first)"
    height = telemetry.position.alt - home.alt + request.up
    if height < (limits.min_clearance_m or 0.0):
        return f"the step would take the robot to {height:.1f} m above the take-off point, below its minimum " \
               f"clearance {limits.min_clearance_m or 0.0:g} m"
    if limits.max_height_m is not None and height > limits.max_height_m:
        return f"the step would take the robot to {height:.1f} m above the take-off point, above the ceiling " \
               f"{limits.max_height_m:g} m"
    return ""


def _generated_area(request: t.Survey | t.Orbit, limits: Limits, cfg: JudgeConfig,
                    telemetry: RobotTelemetry | None) -> str:
    """A survey's polygon / an orbit's circle against the robot's range and geofence, its height against the
    clearance and the ceiling (heights above the take-off point): why not, or ""."""
    if limits.min_clearance_m is not None and request.height < limits.min_clearance_m:
        return f"height {request.height:g} m above the take-off point is under the minimum clearance " \
               f"{limits.min_clearance_m:g} m"
    if limits.max_height_m is not None and request.height > limits.max_height_m:
        return f"height {request.height:g} m above the take-off point is above the ceiling {limits.max_height_m:g} m"
    if isinstance(request, t.Survey):
        places = [(f"polygon vertex {i}", v.lat, v.lon, 0.0) for i, v in enumerate(request.polygon)]
    else:
        places = [("orbit", request.lat, request.lon, request.radius)]
    pos = telemetry.position if telemetry else None
    for label, lat, lon, radius in places:
        if pos is not None:
            d = distance_m(pos.lat, pos.lon, lat, lon) + radius
            if d > cfg.max_range_m:
                return f"{label} reaches {d / 1000:.1f} km from the robot (max {cfg.max_range_m / 1000:g} km)"
        fence = limits.geofence
        if fence is not None:
            d = distance_m(fence.lat, fence.lon, lat, lon) + radius
            if d > fence.radius_m:
                return (f"{label} ({lat:.6f}, {lon:.6f}) reaches outside the geofence: {d:.0f} m from its centre, "
                        f"radius {fence.radius_m:g} m")
    return ""


def _check_points(points: list[tuple[str, float, float, float | None]], limits: Limits, cfg: JudgeConfig,
                  telemetry: RobotTelemetry | None, home: GeoPoint | None) -> str:
    pos = telemetry.position if telemetry else None
    ground = home.alt if home is not None else None
    if ground is None and (limits.min_clearance_m is not None or limits.max_height_m is not None):
        return "the take-off point (ground reference for heights) is not known yet; no telemetry position"
    for label, lat, lon, alt in points:
        if not math.isnan(lat):
            if pos is not None:
                d = distance_m(pos.lat, pos.lon, lat, lon)
                if d > cfg.max_range_m:
                    return f"{label} is {d / 1000:.1f} km from the robot (max {cfg.max_range_m / 1000:g} km)"
            fence = limits.geofence
            if fence is not None:
                d = distance_m(fence.lat, fence.lon, lat, lon)
                if d > fence.radius_m:
                    return (f"{label} ({lat:.6f}, {lon:.6f}) is outside the geofence: {d:.0f} m from its centre, "
                            f"radius {fence.radius_m:g} m")
        if alt is not None and ground is not None:
            height = alt - ground
            if limits.min_clearance_m is not None and height < limits.min_clearance_m:
                return (f"{label} altitude {alt:g} m above sea level is {height:g} m above the take-off point "
                        f"({ground:g} m); the minimum clearance is {limits.min_clearance_m:g} m")
            if limits.max_height_m is not None and height > limits.max_height_m:
                return (f"{label} altitude {alt:g} m above sea level is {height:g} m above the take-off point; "
                        f"the ceiling is {limits.max_height_m:g} m")
    return ""


# ---------------------------------------------------------------- return (PX4's RTL)


def return_path(pos: GeoPoint, home: GeoPoint, limits: Limits, cfg: JudgeConfig) -> list[t.Waypoint]:
    """The path of a ``return`` from ``pos``: up (or down) to the return height where the robot is, then home at
    that height. No separate vertical leg when the robot is already within ``altitude_tolerance_m`` of that height,
    or already above home (within ``position_tolerance_m``): the home waypoint alone takes it there."""
    height = limits.return_height_m
    if height is None:
        height = max(pos.alt - home.alt, limits.min_clearance_m or 0.0)
    alt = home.alt + height
    out = []
    if abs(pos.alt - alt) > cfg.altitude_tolerance_m and distance_m(pos.lat, pos.lon, home.lat, home.lon) > \
            cfg.position_tolerance_m:
        out.append(t.Waypoint(lat=pos.lat, lon=pos.lon, alt=alt))
    out.append(t.Waypoint(lat=home.lat, lon=home.lon, alt=alt))
    return out


def return_request(tel: RobotTelemetry | None, home: GeoPoint | None, limits: Limits,
                   cfg: JudgeConfig) -> t.Goto | str:
    """The ``return`` failsafe's task: a goto along :func:`return_path` (at the cruise speed), or why there is none
    (the robot on the ground, or where it is or its take-off point not known)."""
    if tel is None or tel.position is None or home is None:
        return "the robot's position or take-off point is not known"
    if not tel.airborne:
        return "the robot is on the ground"
    return t.Goto(waypoints=return_path(tel.position, home, limits, cfg))


def is_return(task: t.TaskInfo) -> bool:
    """A goto the failsafe started is its return (the failsafe's other actions are ``hold`` and ``land``): told
    from the task book's record alone, so a RAL restarted during the return still lands it."""
    return task.origin == "failsafe" and task.kind == "goto"


def after_completed(task: t.TaskInfo, limits: Limits) -> t.TaskParams | None:
    """The task the RAL starts when ``task`` completes: a return (:func:`is_return`) ends with ``RETURN_ACTION``
    (``land``: a landing where it arrived; ``hover``: nothing, the robot holds there). Every other task: None."""
    if is_return(task) and limits.return_action == "land":
        return t.Land()
    return None


# ---------------------------------------------------------------- judging a running task


@dataclass(frozen=True)
class Progress:
    """What the judge remembers about one running task."""

    started: float
    seen_queue: bool = False
    seen_airborne: bool = False
    best: float | None = None
    """Best (smallest) distance-to-go seen so far, metres."""
    progress_at: float = 0.0
    next_wp: int = 0
    """Index in the task's path of the waypoint the robot flies to (:func:`next_waypoint`)."""
    origin: GeoPoint | None = None
    """Where the robot was when first judged: the start of the path's first leg."""


@dataclass(frozen=True)
class Verdict:
    progress: Progress
    status: str = "running"
    """``running``, ``completed`` or ``failed``."""
    detail: str = ""


def _local(ref: GeoPoint | t.Waypoint, lat: float, lon: float) -> tuple[float, float]:
    """North, east metres of (lat, lon) from ``ref`` (bbcs.geodesy's scale at ``ref``, as :func:`distance_m`)."""
    east, north = local_en(ref.lat, ref.lon, lat, lon)
    return north, east


def _to_segment(p: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
    """Horizontal distance from ``p`` to the segment ``a``-``b`` (metres, local frame)."""
    dn, de = b[0] - a[0], b[1] - a[1]
    length2 = dn * dn + de * de
    u = 0.0 if length2 == 0.0 else max(0.0, min(1.0, ((p[0] - a[0]) * dn + (p[1] - a[1]) * de) / length2))
    return math.hypot(p[0] - a[0] - u * dn, p[1] - a[1] - u * de)


def next_waypoint(path: Sequence[t.Waypoint], pos: GeoPoint, queued: int | None, previous: int,
                  origin: GeoPoint | None, tolerance_m: float) -> int:
    """Index of the waypoint the robot flies to now.

    The robot's own queue says it when it holds part of this path (``0 < queued <= len(path)``: the last
    ``queued`` waypoints are still to fly). Otherwise (no queue, an empty one, such as the onboard follower's, or
    one longer than the path, still the previous path's) the legs tell it: from ``previous``, a waypoint is passed
    once the robot is within ``tolerance_m`` of it, or nearer the leg after it than the leg before it (the first
    leg starts at ``origin``)."""
    n = len(path)
    if queued is not None and 0 < queued <= n:
        return n - queued
    i = min(max(previous, 0), n - 1)
    ref = path[0]
    here = _local(ref, pos.lat, pos.lon)
    while i < n - 1:
        at = _local(ref, path[i].lat, path[i].lon)
        before = _local(ref, path[i - 1].lat, path[i - 1].lon) if i > 0 else (
            _local(ref, origin.lat, origin.lon) if origin is not None else at)
        after = _local(ref, path[i + 1].lat, path[i + 1].lon)
        reached = math.hypot(here[0] - at[0], here[1] - at[1]) <= tolerance_m
        if not (reached or _to_segment(here, at, after) < _to_segment(here, before, at)):
            break
        i += 1
    return i


def path_to_go(path: Sequence[t.Waypoint], pos: GeoPoint, index: int) -> float:
    """Distance still to fly along ``path`` from ``pos`` through waypoint ``index`` to the end (metres; horizontal
    plus vertical, leg by leg)."""
    w = path[index]
    togo = distance_m(pos.lat, pos.lon, w.lat, w.lon) + abs(pos.alt - w.alt)
    for a, b in zip(path[index:], path[index + 1:], strict=False):
        togo += distance_m(a.lat, a.lon, b.lat, b.lon) + abs(b.alt - a.alt)
    return togo


def judge(task: t.TaskInfo, progress: Progress, tel: RobotTelemetry, home: GeoPoint | None, limits: Limits,
          cfg: JudgeConfig, now: float, generated: Sequence[t.Waypoint] | None = None) -> Verdict:
    """Has ``task`` completed, stalled, or is it still running, given ``tel`` at ``now``? ``generated``: the path
    the trajectory generator planned for a survey/orbit (None until it published it).

    A path task progresses while the distance still to fly along its path (:func:`path_to_go`, from the waypoint
    the robot flies to, :func:`next_waypoint`) shrinks: a path of any length flown at any speed never stalls, a
    robot that hovers fails after ``stall_s``. When the queue grows (the path is still being loaded) the best
    distance starts again from there."""
    req = task.params
    if req is None or isinstance(req, t.LookAt | t.SetPanTilt | t.Hold | t.Track | t.FollowVisionPath | t.Bridge
                                 | t.Manual):
        return Verdict(progress)  # continuous: runs until replaced, cancelled or aborted
    pr = replace(progress, seen_queue=progress.seen_queue or bool(tel.waypoints_queued),
                 seen_airborne=progress.seen_airborne or bool(tel.airborne))
    pos = tel.position
    if pos is None:
        return _stalled(pr, cfg, now)
    if pr.origin is None:
        pr = replace(pr, origin=pos)
    settled = now - pr.started >= cfg.settle_s
    if isinstance(req, t.Survey | t.Orbit) and not generated:
        return _stalled(pr, cfg, now)  # no path yet: the generator's answer is awaited by the RAL
    if isinstance(req, t.Goto | t.FollowPath | t.Survey | t.Orbit):
        path = req.waypoints if isinstance(req, t.Goto | t.FollowPath) else generated
        assert path
        # the onboard follower (path mode 3) keeps the trajectory itself: whatever the DSP's queue holds (a path
        # of the task before, until the mode's INVALIDATE_PATH is applied) is not what the aircraft flies
        queued = None if isinstance(req, t.FollowPath) and req.follower == "onboard" else tel.waypoints_queued
        last = path[-1]
        horiz = distance_m(pos.lat, pos.lon, last.lat, last.lon)
        near = horiz <= cfg.position_tolerance_m and abs(pos.alt - last.alt) <= cfg.altitude_tolerance_m
        if (near and queued in (0, None) and (pr.seen_queue or settled)
                and _stopped(tel, cfg.arrival_speed_mps)):
            return Verdict(pr, "completed")
        index = next_waypoint(path, pos, queued, pr.next_wp, pr.origin, cfg.position_tolerance_m)
        togo = path_to_go(path, pos, index)
        if index < pr.next_wp:  # the queue grew: a path being loaded, not a robot going backwards
            pr = replace(pr, next_wp=index, best=togo)
        pr = replace(pr, next_wp=index)
    elif isinstance(req, t.TakeOff):
        base = home.alt if home is not None else None
        if base is None:
            return _stalled(pr, cfg, now)
        target = base + (limits.takeoff_height_m if limits.takeoff_height_m is not None else req.height)
        if tel.airborne is not False and pos.alt >= target - cfg.altitude_tolerance_m:
            return Verdict(pr, "completed")
        togo = target - pos.alt
    else:  # Land
        if tel.airborne is False and (pr.seen_airborne or settled):
            return Verdict(pr, "completed")
        togo = pos.alt - (home.alt if home is not None else 0.0)
    if pr.best is None or togo < pr.best - MIN_PROGRESS_M:
        pr = replace(pr, best=togo, progress_at=now)
    return _stalled(pr, cfg, now)


def _stopped(tel: RobotTelemetry, speed_mps: float) -> bool:
    """Whether the robot is no faster than ``speed_mps`` (horizontally and vertically); True without a velocity."""
    v = tel.velocity
    return v is None or (math.hypot(v.vn, v.ve) <= speed_mps and abs(v.vd) <= speed_mps)


def _stalled(pr: Progress, cfg: JudgeConfig, now: float) -> Verdict:
    since = max(pr.progress_at, pr.started)
    if now - since >= cfg.stall_s:
        return Verdict(pr, "failed", f"no progress for {now - since:.0f} s (the aircraft is not doing the task)")
    return Verdict(pr)


# ---------------------------------------------------------------- pan & tilt kept where the task put it

PT_RESEND_S = 2.0
"""A pan & tilt task's angles are sent again when, this long after they were last sent, the telemetry shows the
gimbal elsewhere."""
PT_TOLERANCE_DEG = 2.0
"""How far the gimbal may be from the task's angles and count as there."""


def pan_tilt_check(req: object, tel: RobotTelemetry | None, sent_at: float, now: float,
                   resend_s: float = PT_RESEND_S, tolerance_deg: float = PT_TOLERANCE_DEG) -> str:
    """Did a ``SetPanTilt`` task's angles arrive? ``"there"`` (the telemetry shows the gimbal at them: done
    checking, whatever moves it later), ``"resend"`` (still away ``resend_s`` after they were sent) or ``"wait"``.

    Pan & tilt's DATOS is an unsafe (best effort) state slot by the seed's contract, and the task runs until
    replaced: one datum lost on its way (a peer link still settling, docs/bus.md) would leave the gimbal pointing away
    while the ground station is told the task runs. Only until the angles are first seen reached: after that another
    source (vision tracking, a route the station swapped) may move the gimbal, and must not be fought. No telemetry
    of the gimbal: nothing to compare, ``"wait"``."""
    if not isinstance(req, t.SetPanTilt) or tel is None or tel.pan_deg is None or tel.tilt_deg is None:
        return "wait"
    pan_off = abs((tel.pan_deg - req.pan + 180.0) % 360.0 - 180.0)
    if pan_off <= tolerance_deg and abs(tel.tilt_deg - req.tilt) <= tolerance_deg:
        return "there"
    return "resend" if now - sent_at >= resend_s else "wait"


# ---------------------------------------------------------------- limits from the robot's .conf


class _ConfLimits(msgspec.Struct, kw_only=True):
    MAX_SPEED: Annotated[float, msgspec.Meta(gt=0.0)]
    CRUISE_SPEED: Annotated[float, msgspec.Meta(gt=0.0)] | None = None
    MIN_CLEARANCE: float | None = None
    MAX_HEIGHT: Annotated[float, msgspec.Meta(gt=0.0)] | None = None
    TAKEOFF_HEIGHT: Annotated[float, msgspec.Meta(gt=0.0)] | None = None
    GEOFENCE: Annotated[list[float], msgspec.Meta(min_length=3, max_length=3)] | None = None
    RETURN_HEIGHT: Annotated[float, msgspec.Meta(gt=0.0)] | None = None
    RETURN_ACTION: Literal["land", "hover"] = "land"


def limits_conf_errors(doc: ConfDocument) -> list[ConfError]:
    """Every mistake in the RAL's part of a parsed .conf (its limits), each with file:line: for ``cromat conf
    check`` and ``cromat launch --check`` (``Ral.conf_errors``); empty when :func:`load_limits` would succeed."""
    errors = doc.errors_for(_ConfLimits)
    if errors:
        return errors
    raw = doc.to_struct(_ConfLimits)
    if raw.CRUISE_SPEED is not None and raw.CRUISE_SPEED > raw.MAX_SPEED:
        entry = doc.entries["CRUISE_SPEED"]
        errors.append(ConfError(f"CRUISE_SPEED {raw.CRUISE_SPEED:g} is above MAX_SPEED {raw.MAX_SPEED:g}",
                                path=doc.path, line=entry.line, column=entry.column))
    if raw.GEOFENCE is not None:
        lat, lon, radius = raw.GEOFENCE
        if not (valid_lat_lon(lat, lon) and radius > 0):
            entry = doc.entries["GEOFENCE"]
            errors.append(ConfError("GEOFENCE must be [latitude, longitude, radius in m > 0]", path=doc.path,
                                    line=entry.line, column=entry.column))
    if raw.RETURN_HEIGHT is not None:
        entry = doc.entries["RETURN_HEIGHT"]
        if raw.MIN_CLEARANCE is not None and raw.RETURN_HEIGHT < raw.MIN_CLEARANCE:
            errors.append(ConfError(f"RETURN_HEIGHT {raw.RETURN_HEIGHT:g} is under MIN_CLEARANCE {raw.MIN_CLEARANCE:g}",
                                    path=doc.path, line=entry.line, column=entry.column))
        if raw.MAX_HEIGHT is not None and raw.RETURN_HEIGHT > raw.MAX_HEIGHT:
            errors.append(ConfError(f"RETURN_HEIGHT {raw.RETURN_HEIGHT:g} is above MAX_HEIGHT {raw.MAX_HEIGHT:g}",
                                    path=doc.path, line=entry.line, column=entry.column))
    return errors


def load_limits(conf_path: str) -> Limits:
    """The RAL's :class:`Limits` from the robot .conf; ConfError (file, line) when a key is wrong (the first of
    :func:`limits_conf_errors`, so the RAL and ``cromat conf check`` never disagree)."""
    doc = load_conf(conf_path)
    errors = limits_conf_errors(doc)
    if errors:
        raise errors[0]
    raw = doc.to_struct(_ConfLimits)
    fence = Geofence(*raw.GEOFENCE) if raw.GEOFENCE is not None else None
    return Limits(max_speed=raw.MAX_SPEED, cruise_speed=raw.CRUISE_SPEED, min_clearance_m=raw.MIN_CLEARANCE,
                  max_height_m=raw.MAX_HEIGHT, geofence=fence, takeoff_height_m=raw.TAKEOFF_HEIGHT,
                  return_height_m=raw.RETURN_HEIGHT, return_action=raw.RETURN_ACTION)
