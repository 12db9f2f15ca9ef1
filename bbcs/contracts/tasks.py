"""Tasks as one typed value that travels GRI → RAL → MRI → Module Manager: the task's parameters and its record.

A task request is a tagged union (the tag is the GRI task kind). Ranges live in the types, so a request that
decodes is in range; what depends on the robot (MAX_SPEED, clearance, geofence) is checked by the RAL.

Altitude references (docs/gcs.md): :data:`AltitudeAMSL` is metres above mean sea level, the reference of the
DSP's waypoints and telemetry positions; :data:`HeightAboveHome` is metres above the take-off point.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from bbcs.contracts.geo import (
    AltitudeAMSL,
    CommandSpeed,
    DegreesSigned90,
    DegreesSigned180,
    HeightAboveHome,
    Latitude,
    Longitude,
    Radians,
    RotorRpm,
    Vertex,
)

Speed = CommandSpeed
"""A task's speed: :data:`~bbcs.contracts.geo.CommandSpeed` (m/s); 0, or above the robot's MAX_SPEED, is refused by
the RAL; none given: the robot's CRUISE_SPEED."""
MAX_WAYPOINTS = 10_000


class Waypoint(msgspec.Struct, frozen=True, kw_only=True):
    """WGS84 degrees; ``alt`` in metres above mean sea level."""

    lat: Latitude
    lon: Longitude
    alt: AltitudeAMSL


Waypoints = Annotated[list[Waypoint], msgspec.Meta(min_length=1, max_length=MAX_WAYPOINTS)]


class TakeOff(msgspec.Struct, frozen=True, kw_only=True, tag="take_off"):
    """Climb to ``height`` metres above the take-off point."""

    height: HeightAboveHome = 10.0


class Land(msgspec.Struct, frozen=True, kw_only=True, tag="land"):
    """Land where the robot is."""


class Goto(msgspec.Struct, frozen=True, kw_only=True, tag="goto"):
    """Fly through ``waypoints`` in order and stop at the last one (speed: the task's, else the cruise speed)."""

    waypoints: Waypoints
    speed: Speed | None = None


class FollowPath(msgspec.Struct, frozen=True, kw_only=True, tag="follow_path"):
    """Follow the path through ``waypoints``; with ``heading`` (radians) the nose holds it (path mode 1).
    ``follower``: ``dsp`` (the DSP's own follower, modes 0/1) or ``onboard`` (the path follower module flies the
    whole path itself, mode 3: docs/control.md); a robot without an onboard follower refuses ``onboard``."""

    waypoints: Waypoints
    speed: Speed | None = None
    heading: Radians | None = None
    follower: Literal["dsp", "onboard"] = "dsp"


class FollowVisionPath(msgspec.Struct, frozen=True, kw_only=True, tag="follow_vision_path"):
    """Follow the paths the perception module writes (each new one replaces the last)."""

    speed: Speed | None = None


class Bridge(msgspec.Struct, frozen=True, kw_only=True, tag="bridge"):
    """Path mode 6: the DSP flies these references (REFS, the seed's ``ref_altura`` as ``ref_altitude``) as they
    are; ``ref_altitude`` above mean sea level."""

    ref_altitude: AltitudeAMSL
    error_longitudinal: Annotated[float, msgspec.Meta(ge=-1000.0, le=1000.0, description="metres")] = 0.0
    error_lateral: Annotated[float, msgspec.Meta(ge=-1000.0, le=1000.0, description="metres")] = 0.0
    ref_heading: Radians = 0.0
    ref_rpm_motor: RotorRpm = 1500.0


class LookAt(msgspec.Struct, frozen=True, kw_only=True, tag="look_at"):
    """Point the pan & tilt at a geographic point (``alt`` above mean sea level) and keep pointing at it."""

    lat: Latitude
    lon: Longitude
    alt: AltitudeAMSL


class SetPanTilt(msgspec.Struct, frozen=True, kw_only=True, tag="pan_tilt"):
    """Hold the pan & tilt at these angles (degrees)."""

    pan: DegreesSigned180
    tilt: DegreesSigned90


class Hold(msgspec.Struct, frozen=True, kw_only=True, tag="hold"):
    """Stay where the robot is (both waypoint queues emptied)."""


class Track(msgspec.Struct, frozen=True, kw_only=True, tag="track"):
    """Point the pan & tilt at what the perception module tracks, until replaced."""


class Survey(msgspec.Struct, frozen=True, kw_only=True, tag="survey"):
    """Lawnmower over ``polygon`` (not closed) at ``height`` above the take-off point, neighbouring lidar swaths
    overlapping by ``overlap``; planned by the trajectory generator (docs/trajectory.md)."""

    polygon: Annotated[list[Vertex], msgspec.Meta(min_length=3, max_length=200)]
    height: HeightAboveHome
    overlap: Annotated[float, msgspec.Meta(ge=0.0, le=0.9)] = 0.2
    speed: Speed | None = None


class Orbit(msgspec.Struct, frozen=True, kw_only=True, tag="orbit"):
    """Circle ``turns`` times around (lat, lon) at ``radius`` metres, ``height`` above the take-off point;
    planned by the trajectory generator."""

    lat: Latitude
    lon: Longitude
    radius: Annotated[float, msgspec.Meta(gt=0.0, le=5000.0, description="metres")]
    height: HeightAboveHome = 20.0
    clockwise: bool = True
    turns: Annotated[float, msgspec.Meta(gt=0.0, le=20.0)] = 1.0
    speed: Speed | None = None


MANUAL_STEP_M = 5.0
"""The largest set-point move one manual command may ask for, per axis."""
ManualStep = Annotated[float, msgspec.Meta(ge=-MANUAL_STEP_M, le=MANUAL_STEP_M, description="metres")]


class Manual(msgspec.Struct, frozen=True, kw_only=True, tag="manual"):
    """Manual hover (seed 002, "Modo Manual"): move the hover set point by these offsets (metres east, north, up;
    degrees of yaw, counter-clockwise) and hold it there until the next command or task. Airborne robots only."""

    east: ManualStep = 0.0
    north: ManualStep = 0.0
    up: ManualStep = 0.0
    yaw: Annotated[float, msgspec.Meta(ge=-45.0, le=45.0, description="degrees, counter-clockwise")] = 0.0


TaskParams = (TakeOff | Land | Goto | FollowPath | FollowVisionPath | Bridge | LookAt | SetPanTilt | Hold | Track
              | Survey | Orbit | Manual)
"""Every task a ground station can send; each occupies its task type until it ends."""
TASK_KINDS: tuple[str, ...] = tuple(t.__struct_config__.tag for t in TaskParams.__args__)  # type: ignore[attr-defined]
MOVEMENT_KINDS = frozenset({"take_off", "land", "goto", "follow_path", "follow_vision_path", "bridge", "hold",
                            "survey", "orbit", "manual"})
"""Kinds that move the aircraft: a new one empties both waypoint queues before anything else goes out."""
GENERATED_KINDS = frozenset({"survey", "orbit"})
"""Kinds whose path the trajectory generator plans (the RAL sends it a request once the task runs)."""


def kind_of(task: msgspec.Struct) -> str:
    """The wire tag of a task (``goto``, ``abort``, ...)."""
    return str(type(task).__struct_config__.tag)


TaskStatus = Literal["running", "completed", "cancelled", "replaced", "aborted", "failed"]
Origin = Literal["gcs", "failsafe", "mri", "fleet"]


class TaskInfo(msgspec.Struct, frozen=True, kw_only=True):
    """One task as the Module Manager's task book records it (the only record of it anywhere)."""

    id: int
    name: str
    """The manifest task it runs."""
    task_type: str
    kind: str = ""
    """The GRI kind (tag of ``params``), empty when started without parameters."""
    params: TaskParams | None = None
    status: TaskStatus = "running"
    started: float = 0.0
    ended: float | None = None
    detail: str = ""
    origin: Origin = "mri"


class TaskData(msgspec.Struct, frozen=True, kw_only=True):
    """A started task's parameters, as the RAL publishes them (its ``task`` slot) once the Module Manager has
    started it: for modules whose mode alone cannot carry them (a take-off height, a speed, a manual step)."""

    task_id: int
    params: TaskParams
