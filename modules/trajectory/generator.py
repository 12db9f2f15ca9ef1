"""Requests (bbcs.contracts.trajectory) to DATOS paths: geodesy around the request, planning, the limits of
the aircraft. Pure: the module only wires this to the bus."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import msgspec
import numpy as np

from bbcs import load_params, struct_param_errors
from bbcs.contracts.path_follower import DatoPuntoSegCam, DatosSegCam
from bbcs.contracts.trajectory import OrbitRequest, SmoothRequest, SurveyRequest, TrajectoryRequest, Vertex
from bbcs.geodesy import LocalFrame
from modules.trajectory import planning
from modules.trajectory.planning import PlanningError


class Limits(msgspec.Struct, frozen=True, kw_only=True):
    """The aircraft and the datum of the path follower's ``altura``: the trajectory module's manifest ``params``
    (ranges in the types; ``cromat launch --check`` and the module load them through the same function)."""

    speed: Annotated[float, msgspec.Meta(gt=0)] = 10.0
    """Survey speed, m/s: with ``max_bank_deg`` it sets the turn radius."""
    max_bank_deg: Annotated[float, msgspec.Meta(gt=0, lt=90)] = 25.0
    ground_altitude: float = 0.0
    """Added to a request's height above the ground to give the waypoints' ``altura``."""
    line_extension: Annotated[float, msgspec.Meta(ge=0)] = 5.0
    """Lines run this far past the polygon before a turn starts (turns are flown outside it)."""
    arc_step_deg: Annotated[float, msgspec.Meta(gt=0, le=45)] = 10.0
    max_points: Annotated[int, msgspec.Meta(ge=2)] = 2000

    @property
    def turn_radius(self) -> float:
        return planning.min_turn_radius(self.speed, self.max_bank_deg)

    @classmethod
    def param_errors(cls, params: dict[str, str]) -> list[tuple[str, str]]:
        """Every problem of the manifest's trajectory ``params``, (key, reason)."""
        return struct_param_errors(cls, params, what="trajectory")

    @classmethod
    def from_params(cls, params: dict[str, str]) -> Limits:
        """Module params (strings); every unknown name or bad value in one ``ParamError`` (exit 78)."""
        return load_params(cls, params, what="trajectory")


@dataclass(frozen=True)
class Plan:
    kind: str
    path: DatosSegCam
    local: np.ndarray
    """The path in the request's local frame (east, north metres)."""
    length_m: float
    spacing_m: float = 0.0
    lines: int = 0
    lower_bound_m: float = 0.0


def _frame(points: list[Vertex]) -> LocalFrame:
    return LocalFrame(float(np.mean([p.lat for p in points])), float(np.mean([p.lon for p in points])))


def _local(frame: LocalFrame, points: list[Vertex]) -> np.ndarray:
    return frame.to_enu([p.lat for p in points], [p.lon for p in points], 0.0)[:, :2]


def _datos(frame: LocalFrame, en: np.ndarray, altura: float, limits: Limits) -> DatosSegCam:
    if len(en) > limits.max_points:
        raise PlanningError(f"the path needs {len(en)} waypoints, more than max_points={limits.max_points}")
    lat, lon, _ = frame.to_geo(en[:, 0], en[:, 1])
    return DatosSegCam(n_points=len(en), puntos=[
        DatoPuntoSegCam(latitud=float(a), longitud=float(o), altura=altura) for a, o in zip(lat, lon, strict=True)])


def plan_survey(req: SurveyRequest, limits: Limits) -> Plan:
    frame = _frame(req.polygon)
    spacing = planning.line_spacing(req.height, req.overlap)
    radius = limits.turn_radius
    if spacing < 2 * radius:
        raise PlanningError(f"line spacing {spacing:.1f} m is under twice the turn radius {radius:.1f} m "
                            f"(speed {limits.speed:g} m/s, bank {limits.max_bank_deg:g}°): fly higher, with less "
                            "overlap, or slower")
    start = _local(frame, [req.start])[0] if req.start is not None else None
    survey = planning.lawnmower(_local(frame, req.polygon), spacing, direction_deg=req.direction_deg, start=start,
                                extension=limits.line_extension, turn_extension=radius)
    path = planning.smooth(survey.waypoints, radius, step_deg=limits.arc_step_deg)
    return Plan("survey", _datos(frame, path, limits.ground_altitude + req.height, limits), path,
                planning.path_length(path), spacing, survey.lines, survey.lower_bound_m)


def plan_orbit(req: OrbitRequest, limits: Limits) -> Plan:
    if req.radius < limits.turn_radius:
        raise PlanningError(f"orbit radius {req.radius:g} m is under the turn radius {limits.turn_radius:.1f} m")
    frame = LocalFrame(req.centre.lat, req.centre.lon)
    path = planning.orbit(np.zeros(2), req.radius, turns=req.turns, clockwise=req.clockwise,
                          step_deg=limits.arc_step_deg)
    return Plan("orbit", _datos(frame, path, limits.ground_altitude + req.height, limits), path,
                planning.path_length(path))


def plan_smooth(req: SmoothRequest, limits: Limits) -> Plan:
    frame = _frame(req.waypoints)
    path = planning.smooth(_local(frame, req.waypoints), limits.turn_radius, step_deg=limits.arc_step_deg)
    return Plan("smooth", _datos(frame, path, limits.ground_altitude + req.height, limits), path,
                planning.path_length(path))


def plan(req: TrajectoryRequest, limits: Limits) -> Plan:
    """The path for a request; ValueError (PlanningError included) says why there is none."""
    kind = req.kind()
    sub = getattr(req, kind)
    result = {"survey": plan_survey, "orbit": plan_orbit, "smooth": plan_smooth}[kind](sub, limits)
    if not all(math.isfinite(p.latitud) and math.isfinite(p.longitud) for p in result.path.puntos):
        raise PlanningError("the path left the valid coordinate range")
    return result
