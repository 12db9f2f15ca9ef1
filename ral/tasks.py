"""The RAL's task queue: one current task per task type, admission, cancel, completion from telemetry.

Pure logic, no bus and no clock of its own (every call takes ``now``), so it is tested in microseconds. The
RAL process turns what it returns into MRI requests and GRI events.

Nothing here is robot-specific: the manifest's task map (``available``: task name → task type) says which
task names a robot has; a GRI task kind is mapped to a manifest task name by ``task_names`` (identity unless
configured), and a kind the robot lacks is rejected with a reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import msgspec

from bbcs.contracts.geo import GeoPoint
from bbcs.contracts.robot import RobotTelemetry
from ral import gri

EARTH_RADIUS_M = 6_371_000.0
CONTINUOUS = frozenset({"look_at", "pan_tilt", "hold", "track"})
"""Kinds that keep their task type busy until replaced, cancelled or aborted (they never 'complete')."""


def distance_m(a_lat: float, a_lon: float, b_lat: float, b_lon: float) -> float:
    """Horizontal distance (equirectangular; metres-accurate over the few km a task spans)."""
    lat0 = math.radians((a_lat + b_lat) / 2)
    dn = math.radians(b_lat - a_lat) * EARTH_RADIUS_M
    de = math.radians(b_lon - a_lon) * EARTH_RADIUS_M * math.cos(lat0)
    return math.hypot(dn, de)


@dataclass(frozen=True)
class QueueConfig:
    position_tolerance_m: float = 3.0
    altitude_tolerance_m: float = 2.0
    settle_s: float = 2.0
    """Without the waypoint queue seen non-empty, a path task may complete only after this."""
    max_range_m: float = 20_000.0
    """Waypoints farther than this from the robot's position (when known) are rejected."""


@dataclass(frozen=True)
class Rejected:
    reason: str


@dataclass(frozen=True)
class Plan:
    """An admitted task: what to ask the manager for."""

    kind: str
    name: str
    task_type: str
    params: dict[str, str]
    request: gri.Task


@dataclass
class _Running:
    info: gri.TaskInfo
    request: gri.Task
    seen_queue: bool = False
    seen_airborne: bool = False
    target_alt: float | None = None


@dataclass
class TaskQueue:
    robot: str
    config: QueueConfig = field(default_factory=QueueConfig)
    task_names: dict[str, str] = field(default_factory=dict)
    """GRI kind → manifest task name (missing: the same name)."""
    available: dict[str, str] = field(default_factory=dict)
    """Manifest task name → task type (from the manager's task list)."""
    current: dict[str, _Running] = field(default_factory=dict)
    next_id: int = 1
    telemetry: RobotTelemetry | None = None
    home: GeoPoint | None = None

    def name_for(self, kind: str) -> str:
        return self.task_names.get(kind, kind)

    # ------------------------------------------------------------ admission

    def admit(self, request: gri.Task) -> Plan | Rejected:
        """Check a decoded task against what this robot has and where it is; nothing changes here."""
        kind = gri.kind_of(request)
        name = self.name_for(kind)
        if not self.available:
            return Rejected("the robot's task list is unknown (Module Manager not answering)")
        task_type = self.available.get(name)
        if task_type is None:
            return Rejected(
                f"robot {self.robot} has no task {name!r} for {kind} "
                f"(available: {', '.join(sorted(self.available)) or 'none'})"
            )
        if isinstance(request, gri.Goto | gri.FollowPath):
            pos = self.telemetry.position if self.telemetry else None
            if pos is not None:
                for i, wp in enumerate(request.waypoints):
                    d = distance_m(pos.lat, pos.lon, wp.lat, wp.lon)
                    if d > self.config.max_range_m:
                        return Rejected(
                            f"waypoint {i} is {d / 1000:.1f} km from the robot "
                            f"(max {self.config.max_range_m / 1000:g} km)"
                        )
        return Plan(kind, name, task_type, _params(request), request)

    # ------------------------------------------------------------ lifecycle

    def start(self, plan: Plan, now: float, origin: str = "gcs") -> tuple[gri.TaskInfo, gri.TaskInfo | None]:
        """Make ``plan`` the current task of its type; returns it and the task it replaced (if any)."""
        info = gri.TaskInfo(
            id=self.next_id,
            kind=plan.kind,
            name=plan.name,
            task_type=plan.task_type,
            status="running",
            started=now,
            origin=origin,
        )  # type: ignore[arg-type]
        self.next_id += 1
        old = self.current.pop(plan.task_type, None)
        replaced = _end(old.info, "replaced", now, f"replaced by task {info.id}") if old else None
        running = _Running(info, plan.request)
        if isinstance(plan.request, gri.TakeOff):
            base = self.home or (self.telemetry.position if self.telemetry else None)
            running.target_alt = None if base is None else base.alt + plan.request.height
        self.current[plan.task_type] = running
        return info, replaced

    def cancel(
        self, task_type: str, now: float, status: str = "cancelled", detail: str = ""
    ) -> gri.TaskInfo | None:
        run = self.current.pop(task_type, None)
        return None if run is None else _end(run.info, status, now, detail)

    def abort(self, now: float) -> list[gri.TaskInfo]:
        return [info for t in sorted(self.current) if (info := self.cancel(t, now, "aborted", "abort"))]

    def fail(self, task_type: str, now: float, detail: str) -> gri.TaskInfo | None:
        return self.cancel(task_type, now, "failed", detail)

    def tasks(self) -> list[gri.TaskInfo]:
        return [self.current[t].info for t in sorted(self.current)]

    # ------------------------------------------------------------ completion

    def on_telemetry(self, tel: RobotTelemetry, now: float) -> list[gri.TaskInfo]:
        """Fold in new telemetry; returns the tasks it completed (removed from the queue)."""
        self.telemetry = tel
        if tel.airborne is False and tel.position is not None:
            self.home = tel.position
        done = []
        for task_type, run in list(self.current.items()):
            if self._complete(run, tel, now):
                del self.current[task_type]
                done.append(_end(run.info, "completed", now, ""))
        return done

    def _complete(self, run: _Running, tel: RobotTelemetry, now: float) -> bool:
        req = run.request
        cfg = self.config
        if tel.waypoints_queued:
            run.seen_queue = True
        if tel.airborne:
            run.seen_airborne = True
        settled = now - run.info.started >= cfg.settle_s
        pos = tel.position
        if isinstance(req, gri.Goto | gri.FollowPath):
            if pos is None or tel.waypoints_queued not in (0, None):
                return False
            last = req.waypoints[-1]
            near = (
                distance_m(pos.lat, pos.lon, last.lat, last.lon) <= cfg.position_tolerance_m
                and abs(pos.alt - last.alt) <= cfg.altitude_tolerance_m
            )
            return near and (run.seen_queue or settled)
        if isinstance(req, gri.TakeOff):
            if pos is None or tel.airborne is False:
                return False
            if run.target_alt is None:
                base = self.home or pos
                run.target_alt = base.alt + req.height
            return pos.alt >= run.target_alt - cfg.altitude_tolerance_m
        if isinstance(req, gri.Land):
            return tel.airborne is False and (run.seen_airborne or settled)
        return False


def _end(info: gri.TaskInfo, status: str, now: float, detail: str) -> gri.TaskInfo:
    return msgspec.structs.replace(info, status=status, ended=now, detail=detail)


def _params(request: gri.Task) -> dict[str, str]:
    """The strings the manager's SetTask carries (a summary; the data itself goes on the RAL's slots)."""
    if isinstance(request, gri.Goto | gri.FollowPath):
        out = {"n_points": str(len(request.waypoints))}
        if request.speed is not None:
            out["speed"] = f"{request.speed:g}"
        return out
    if isinstance(request, gri.TakeOff):
        return {"height": f"{request.height:g}"}
    if isinstance(request, gri.LookAt):
        return {"lat": repr(request.lat), "lon": repr(request.lon), "alt": repr(request.alt)}
    if isinstance(request, gri.SetPanTilt):
        return {"pan": f"{request.pan:g}", "tilt": f"{request.tilt:g}"}
    return {}
