"""What a ground station (or any module) asks of the trajectory generator (``modules/trajectory``).

One ``TrajectoryRequest`` on the generator's ``request`` input, exactly one of ``survey``, ``orbit``,
``smooth`` set; the answer is a ``TrajectoryStatus`` on its ``status`` output (same ``request_id``), and on
success the path on the matching DATOS stream output (docs/trajectory.md). Angles in degrees, lengths in
metres, positions WGS84.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from bbcs.contracts.geo import Vertex

Height = Annotated[float, msgspec.Meta(gt=0.0, le=3000.0)]
"""Flight height above the ground, metres."""


class SurveyRequest(msgspec.Struct, frozen=True, kw_only=True):
    """Lawnmower over ``polygon`` (3 to 200 vertices, not closed) at ``height`` above the ground, lines
    spaced so neighbouring LD-MRS swaths overlap by ``overlap`` (0.2 = 20 %)."""

    polygon: Annotated[list[Vertex], msgspec.Meta(min_length=3, max_length=200)]
    height: Height
    overlap: Annotated[float, msgspec.Meta(ge=0.0, le=0.9)] = 0.2
    start: Vertex | None = None
    """Where the aircraft is: the entry corner and direction are chosen to shorten the whole flight from
    here. None: only the survey's own length counts."""
    direction_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] | None = None
    """Line direction (degrees clockwise from north); None: the one that gives the shortest path."""


class OrbitRequest(msgspec.Struct, frozen=True, kw_only=True):
    centre: Vertex
    radius: Annotated[float, msgspec.Meta(gt=0.0, le=5000.0)]
    height: Height
    clockwise: bool = True
    turns: Annotated[float, msgspec.Meta(gt=0.0, le=20.0)] = 1.0


class SmoothRequest(msgspec.Struct, frozen=True, kw_only=True):
    """Waypoints to join with turns the aircraft can fly (corners replaced by arcs of at least the
    generator's minimum turn radius)."""

    waypoints: Annotated[list[Vertex], msgspec.Meta(min_length=2, max_length=1000)]
    height: Height


class TrajectoryRequest(msgspec.Struct, frozen=True, kw_only=True):
    request_id: Annotated[int, msgspec.Meta(ge=0, le=2**31 - 1)]
    survey: SurveyRequest | None = None
    orbit: OrbitRequest | None = None
    smooth: SmoothRequest | None = None
    check_only: bool = False
    """Plan and answer the status, but publish no path: the RAL asks this before it starts a survey or an orbit,
    so a plan the generator refuses is refused before the running task is replaced."""

    def kind(self) -> str:
        """The one request set; ValueError unless exactly one is."""
        given = [k for k in ("survey", "orbit", "smooth") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"exactly one of survey, orbit, smooth must be given, not {given or 'none'}")
        return given[0]


class TrajectoryStatus(msgspec.Struct, frozen=True, kw_only=True):
    request_id: int
    kind: Literal["survey", "orbit", "smooth", ""]
    accepted: bool
    reason: str
    """Why it was refused (empty when accepted)."""
    n_points: int = 0
    path_length_m: float = 0.0
    line_spacing_m: float = 0.0
    lines: int = 0
