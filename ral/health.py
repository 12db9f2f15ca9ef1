"""Health from the robot's own telemetry: a loss of control seen by the robot itself (issue 30, case 4).

A starved flight loop let a quadrotor touch the ground at 53° of roll, or fall and spin 43 m away from home, while
the GRI said "airborne, goto running, no errors". The RAL now judges every robot's :class:`RobotTelemetry` (any
kind: a field the robot does not report turns its detector off) with five rules, each a small state machine on
the telemetry's own stamps (pure: no bus, no clock of its own):

- ``robot`` (critical): the telemetry's ``error_code`` is one its robot kind uses to say it lost control itself
  (``bbcs.contracts.error_codes.LOSS_OF_CONTROL_CODES``: the uQuad's 706, its tumble cut), at once: the robot's
  own estimate runs at its frame rate, the rules below see it at the telemetry's;
- ``attitude`` (critical): the tilt (from roll and pitch) beyond ``max_tilt_deg`` for ``tilt_s``;
- ``ground`` (critical): airborne at or below ``ground_m`` above the take-off point, after having been above
  ``ground_clear_m`` since it left the ground, with no landing running;
- ``off_path`` (error): farther than ``max_off_m`` for ``off_s`` from where the running movement task keeps the
  robot (the path from where the task started through its waypoints, the column above a take-off or landing, a
  hold's point);
- ``spin`` (critical): airborne, the heading turning faster than ``max_yaw_rate_dps`` on average over ``spin_s``.

Each detector reports once per episode (again only after its condition has been clear for ``clear_s``). The first
fault of an episode, while airborne, asks for the robot's health action (``action_critical`` or ``action_error``:
``land``, ``hold``, ``none``); the RAL then records the error with its severity (GRI ``errors``), fails the running
movement tasks with the reason and runs the action as a failsafe. The thresholds are the ``HEALTH: limits`` group
of the robot's .conf (docs/health.md lists the keys and defaults). A robot kind may act
faster on its own (the uQuad cuts its motors when its estimate shows it tumbling, docs/uquad.md).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Annotated, Literal

import msgspec

from bbcs import ConfDocument, ConfError, load_conf
from bbcs.contracts import tasks as t
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.contracts.safety import Severity
from bbcs.geodesy import local_en
from ral.failsafe import FailsafeAction
from ral.tasks import limits_conf_errors

HealthAction = Literal["land", "hold", "none"]
Detector = Literal["robot", "attitude", "ground", "off_path", "spin"]
MOVEMENT_KINDS = frozenset({"take_off", "land", "goto", "follow_path", "follow_vision_path", "hold", "survey",
                            "orbit", "manual", "bridge"})
"""GRI kinds of the tasks that move the robot: the ones a loss of control fails."""
CONF_GROUP = ("HEALTH", "limits")

_NonNeg = Annotated[float, msgspec.Meta(ge=0.0)]
_Pos = Annotated[float, msgspec.Meta(gt=0.0)]


class HealthConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The ``HEALTH: limits`` group of the robot's .conf; every key optional (these defaults)."""

    enabled: bool = True
    max_tilt_deg: Annotated[float, msgspec.Meta(gt=0.0, le=180.0)] = 45.0
    tilt_s: _NonNeg = 0.2
    ground_m: _NonNeg = 0.3
    ground_clear_m: _Pos = 1.0
    max_off_m: _Pos = 30.0
    off_s: _NonNeg = 3.0
    max_yaw_rate_dps: _Pos = 120.0
    spin_s: _Pos = 3.0
    """With ``max_yaw_rate_dps`` 120: a full turn. A turn towards a waypoint (half a turn at most) is never a spin."""
    clear_s: _NonNeg = 2.0
    action_critical: HealthAction = "land"
    action_error: HealthAction = "hold"


@dataclass(frozen=True)
class HealthFault:
    """One loss of control seen in the telemetry, and what the RAL must do about it."""

    detector: Detector
    severity: Severity
    detail: str
    stamp: float
    """The telemetry stamp at which it was decided."""
    action: FailsafeAction | None = None
    """Set on the first fault of an episode while airborne: the failsafe to run."""
    fail: tuple[t.TaskInfo, ...] = ()
    """The running movement tasks it fails."""


@dataclass
class _Persist:
    """A condition that must hold for ``hold_s`` (telemetry time) before it is a fault, reported once."""

    since: float | None = None
    reported: bool = False
    clear_since: float | None = None

    def update(self, bad: bool, now: float, hold_s: float, clear_s: float) -> bool:
        """True exactly once per episode: when ``bad`` has held for ``hold_s``."""
        if bad:
            self.clear_since = None
            self.since = now if self.since is None else self.since
            if not self.reported and now - self.since >= hold_s:
                self.reported = True
                return True
            return False
        self.since = None
        if self.reported:
            self.clear_since = now if self.clear_since is None else self.clear_since
            if now - self.clear_since >= clear_s:
                self.reported = False
                self.clear_since = None
        return False


@dataclass
class HealthMonitor:
    cfg: HealthConfig = field(default_factory=HealthConfig)
    loss_codes: frozenset[int] = frozenset()
    """Telemetry ``error_code`` values by which this robot says it lost control (the ``robot`` rule)."""
    _last: float | None = None
    _persist: dict[str, _Persist] = field(default_factory=lambda: {d: _Persist() for d in
                                                                   ("robot", "attitude", "ground", "off_path", "spin")})
    _cleared_ground: bool = False
    _headings: deque[tuple[float, float]] = field(default_factory=deque)
    """(stamp, heading unwrapped) of the last ``spin_s`` and a bit."""
    _starts: dict[int, GeoPoint] = field(default_factory=dict)
    """Task id → the position where the telemetry first saw it running."""
    _acting: bool = False
    """A health action was asked and the robot has not been seen on the ground since."""
    faults: int = 0

    def update(self, tel: RobotTelemetry, running: list[t.TaskInfo], home: GeoPoint | None) -> list[HealthFault]:
        """Judge one telemetry sample (older or repeated ones are ignored); the faults it completes."""
        cfg = self.cfg
        now = tel.stamp
        if not cfg.enabled or (self._last is not None and now <= self._last):
            return []
        self._last = now
        moving = [i for i in running if i.kind in MOVEMENT_KINDS]
        for info in moving:
            if info.id not in self._starts and tel.position is not None:
                self._starts[info.id] = tel.position
        for gone in set(self._starts) - {i.id for i in moving}:
            del self._starts[gone]
        if tel.airborne is False:
            self._cleared_ground = False
            self._acting = False
        found: list[tuple[Detector, Severity, str]] = []
        rules: tuple[tuple[Detector, str | None, float], ...] = (
            ("robot", self._robot(tel), 0.0),
            ("attitude", self._attitude(tel), cfg.tilt_s),
            ("ground", self._ground(tel, home, moving), 0.0),
            ("off_path", self._off_path(tel, moving), cfg.off_s),
            ("spin", self._spin(tel), 0.0),
        )
        for detector, why, hold_s in rules:
            if self._persist[detector].update(why is not None, now, hold_s, cfg.clear_s) and why is not None:
                found.append((detector, Severity.ERROR if detector == "off_path" else Severity.CRITICAL, why))
        if not any(p.reported for p in self._persist.values()):
            self._acting = False  # the episode is over: a later one may act again
        if self._acting:  # the action this episode asked is what the robot does about it: not failed by it
            moving = [i for i in moving if not (i.origin == "failsafe" and i.kind in ("land", "hold"))]
        out = []
        for detector, severity, why in found:
            self.faults += 1
            action: FailsafeAction | None = None
            if tel.airborne and not self._acting:
                chosen = cfg.action_critical if severity is Severity.CRITICAL else cfg.action_error
                if chosen != "none":
                    action = FailsafeAction(chosen)
                    self._acting = True
            out.append(HealthFault(detector, severity, f"loss of control ({detector}): {why}", now, action,
                                   tuple(moving)))
            moving = []  # failed once, by the first fault
        return out

    # ------------------------------------------------------------ the five rules: why it is a fault, or None

    def _robot(self, tel: RobotTelemetry) -> str | None:
        code = tel.error_code
        if code is not None and code in self.loss_codes:
            return f"the robot reports it lost control (error {code})"
        return None

    def _attitude(self, tel: RobotTelemetry) -> str | None:
        a = tel.attitude
        if a is None:
            return None
        tilt = tilt_deg(a.roll, a.pitch)
        if tilt > self.cfg.max_tilt_deg:
            return f"tilted {tilt:.0f}° (roll {a.roll:.0f}°, pitch {a.pitch:.0f}°; limit {self.cfg.max_tilt_deg:g}°)"
        return None

    def _ground(self, tel: RobotTelemetry, home: GeoPoint | None, moving: list[t.TaskInfo]) -> str | None:
        if not tel.airborne or home is None or tel.position is None:
            return None
        height = tel.position.alt - home.alt
        if height > self.cfg.ground_clear_m:
            self._cleared_ground = True
        landing = any(i.kind == "land" for i in moving)
        if self._cleared_ground and not landing and height <= self.cfg.ground_m:
            return f"on the ground while airborne ({height:.2f} m above the take-off point, no landing running)"
        return None

    def _off_path(self, tel: RobotTelemetry, moving: list[t.TaskInfo]) -> str | None:
        if not tel.airborne or tel.position is None:
            return None
        worst: tuple[float, t.TaskInfo] | None = None
        for info in moving:
            start = self._starts.get(info.id)
            if start is None:
                continue
            d = distance_from_task(info.params, start, tel.position)
            if d is not None and (worst is None or d > worst[0]):
                worst = (d, info)
        if worst is not None and worst[0] > self.cfg.max_off_m:
            d, info = worst
            return f"{d:.1f} m from where its {info.kind} task keeps it (limit {self.cfg.max_off_m:g} m)"
        return None

    def _spin(self, tel: RobotTelemetry) -> str | None:
        heading = tel.heading_deg if tel.heading_deg is not None else (tel.attitude.yaw if tel.attitude else None)
        if heading is None or not math.isfinite(heading) or not tel.airborne:  # carried or set up on the ground
            self._headings.clear()
            return None
        h = self._headings
        unwrapped = heading if not h else h[-1][1] + (heading - h[-1][1] + 180.0) % 360.0 - 180.0
        h.append((tel.stamp, unwrapped))
        # keep the newest sample at least spin_s old (the window's start) and everything after it
        while len(h) > 2 and tel.stamp - h[1][0] >= self.cfg.spin_s:
            h.popleft()
        span = tel.stamp - h[0][0]
        if span < self.cfg.spin_s or len(h) < 3:  # one step between two samples cannot tell a turn's direction
            return None
        rate = (h[-1][1] - h[0][1]) / span
        if abs(rate) > self.cfg.max_yaw_rate_dps:
            return f"heading turning {abs(rate):.0f}°/s over {span:.1f} s (limit {self.cfg.max_yaw_rate_dps:g}°/s)"
        return None


# ---------------------------------------------------------------- geometry


def tilt_deg(roll: float, pitch: float) -> float:
    """The angle between the body's up axis and the vertical (0 level, 180 upside down)."""
    c = math.cos(math.radians(roll)) * math.cos(math.radians(pitch))
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def _enu(ref: GeoPoint, p: GeoPoint | t.Waypoint) -> tuple[float, float, float]:
    """Metres east, north, up of ``p`` from ``ref`` (bbcs.geodesy's local frame at ``ref``)."""
    east, north = local_en(ref.lat, ref.lon, p.lat, p.lon)
    return east, north, p.alt - ref.alt


def _to_segment(p: tuple[float, ...], a: tuple[float, ...], b: tuple[float, ...]) -> float:
    ab = [y - x for x, y in zip(a, b, strict=True)]
    ap = [y - x for x, y in zip(a, p, strict=True)]
    n2 = sum(c * c for c in ab)
    k = 0.0 if n2 == 0.0 else max(0.0, min(1.0, sum(x * y for x, y in zip(ab, ap, strict=True)) / n2))
    return math.dist(p, [x + k * c for x, c in zip(a, ab, strict=True)])


def distance_from_task(params: t.TaskParams | None, start: GeoPoint, pos: GeoPoint) -> float | None:
    """How far ``pos`` is from where the task keeps the robot, it having started at ``start``: the path from
    ``start`` through a goto's waypoints; the vertical above ``start`` for a take-off or a landing (horizontal
    distance); ``start`` itself for a hold. None for tasks whose path the RAL does not hold (survey, orbit: the
    generator's; manual: the module's)."""
    p = _enu(start, pos)
    if isinstance(params, t.Goto | t.FollowPath):
        points = [(0.0, 0.0, 0.0), *(_enu(start, w) for w in params.waypoints)]
        return min(_to_segment(p, a, b) for a, b in zip(points, points[1:], strict=False))
    if isinstance(params, t.TakeOff | t.Land):
        return math.hypot(p[0], p[1])
    if isinstance(params, t.Hold):
        return math.dist(p, (0.0, 0.0, 0.0))
    return None


# ---------------------------------------------------------------- the robot's .conf


def health_conf_errors(doc: ConfDocument) -> list[ConfError]:
    """Every mistake in the ``HEALTH: limits`` group (none when it is absent), each with file:line."""
    groups = [g for g in doc.groups if (g.type, g.name) == CONF_GROUP]
    return [e for g in groups for e in g.errors_for(HealthConfig)]


def ral_conf_errors(doc: ConfDocument) -> list[ConfError]:
    """The RAL's check of its part of a robot .conf: its limits and its health thresholds."""
    return [*limits_conf_errors(doc), *health_conf_errors(doc)]


def load_health(conf_path: str) -> HealthConfig:
    """The health thresholds of the robot's .conf (defaults without a ``HEALTH: limits`` group); ConfError (file,
    line) for the first mistake."""
    doc = load_conf(conf_path)
    errors = health_conf_errors(doc)
    if errors:
        raise errors[0]
    group = next((g for g in doc.groups if (g.type, g.name) == CONF_GROUP), None)
    return group.to_struct(HealthConfig) if group is not None else HealthConfig()
