"""The GRI (General Robot Interface): what every robot shows ground stations and other robots.

| key | what |
| --- | --- |
| ``cromat/<robot>/@ral/state``  | :class:`GriState`, safe state (a late joiner gets the last one) |
| ``cromat/<robot>/@ral/events`` | :class:`GriEvent`, safe stream |
| ``cromat/<robot>/@ral/task``   | queryable: a :data:`TaskRequest` (msgpack) in, a :class:`TaskReply` out |
| ``cromat/@gcs/<name>``         | liveliness token of a ground station holding a link |
| ``cromat/@gcs/<name>/heartbeat`` | :class:`GcsHeartbeat` from that ground station |

Task requests are one tagged union; ranges live in the types, so a request that decodes is a valid request
(waypoint out of range, unknown task tag: refused at decoding with msgspec's message).
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from bbcs import keys
from bbcs.contracts.geo import (
    AltitudeEllipsoid,
    Attitude,
    DegreesSigned90,
    DegreesSigned180,
    GeoPoint,
    Latitude,
    Longitude,
    VelocityNED,
)

Speed = Annotated[float, msgspec.Meta(gt=0.0, le=100.0)]
MAX_WAYPOINTS = 10_000

STATE = "state"
EVENTS = "events"
TASK = "task"


# ---------------------------------------------------------------- task requests


class Waypoint(msgspec.Struct, frozen=True, kw_only=True):
    """WGS84 degrees, metres."""

    lat: Latitude
    lon: Longitude
    alt: AltitudeEllipsoid


Waypoints = Annotated[list[Waypoint], msgspec.Meta(min_length=1, max_length=MAX_WAYPOINTS)]


class TakeOff(msgspec.Struct, frozen=True, kw_only=True, tag="take_off"):
    """Climb to ``height`` metres above the take-off point."""

    height: Annotated[float, msgspec.Meta(ge=1.0, le=500.0)] = 10.0


class Land(msgspec.Struct, frozen=True, kw_only=True, tag="land"):
    """Land where the robot is."""


class Goto(msgspec.Struct, frozen=True, kw_only=True, tag="goto"):
    """Fly through ``waypoints`` in order and stop at the last one."""

    waypoints: Waypoints
    speed: Speed | None = None


class FollowPath(msgspec.Struct, frozen=True, kw_only=True, tag="follow_path"):
    """Follow the path through ``waypoints`` (the onboard path follower's task in the manifest's task map)."""

    waypoints: Waypoints
    speed: Speed | None = None


class LookAt(msgspec.Struct, frozen=True, kw_only=True, tag="look_at"):
    """Point the pan & tilt at a geographic point and keep pointing at it."""

    lat: Latitude
    lon: Longitude
    alt: AltitudeEllipsoid


class SetPanTilt(msgspec.Struct, frozen=True, kw_only=True, tag="pan_tilt"):
    """Hold the pan & tilt at these angles (degrees)."""

    pan: DegreesSigned180
    tilt: DegreesSigned90


class Hold(msgspec.Struct, frozen=True, kw_only=True, tag="hold"):
    """Stay where the robot is."""


class Track(msgspec.Struct, frozen=True, kw_only=True, tag="track"):
    """Perception: point the pan & tilt at what the robot's perception module tracks, until replaced."""


class Abort(msgspec.Struct, frozen=True, kw_only=True, tag="abort"):
    """Stop every running task now (the robot holds); not queued, always handled first."""


class Cancel(msgspec.Struct, frozen=True, kw_only=True, tag="cancel"):
    """End the running task of one type (``movement``, ``pan_tilt``, ... as the manifest names them)."""

    task_type: str


Task = TakeOff | Land | Goto | FollowPath | LookAt | SetPanTilt | Hold | Track
"""Tasks that occupy a task type until completed, replaced, cancelled or aborted."""
TaskRequest = TakeOff | Land | Goto | FollowPath | LookAt | SetPanTilt | Hold | Track | Abort | Cancel
TASK_KINDS: tuple[str, ...] = tuple(t.__struct_config__.tag for t in Task.__args__)  # type: ignore[attr-defined]


def kind_of(request: msgspec.Struct) -> str:
    """The wire tag of a request (``goto``, ``abort``, ...)."""
    return str(type(request).__struct_config__.tag)


class TaskReply(msgspec.Struct, frozen=True, kw_only=True):
    accepted: bool
    reason: str = ""
    """Why it was rejected (empty when accepted)."""
    task_id: int = 0
    task_type: str = ""


# ---------------------------------------------------------------- state and events

TaskStatus = Literal["running", "completed", "cancelled", "replaced", "aborted", "failed"]
LinkState = Literal["no_gcs", "up", "lost", "failsafe"]


class TaskInfo(msgspec.Struct, frozen=True, kw_only=True):
    id: int
    kind: str
    """GRI task tag (``goto``...)."""
    name: str
    """The manifest task it was mapped to."""
    task_type: str
    status: TaskStatus
    started: float
    ended: float | None = None
    detail: str = ""
    origin: Literal["gcs", "failsafe"] = "gcs"


class ModuleHealth(msgspec.Struct, frozen=True, kw_only=True):
    name: str
    state: str
    restarts: int = 0
    last_exit: int | None = None
    reason: str = ""
    last_error: int | None = None
    routes: dict[str, int] = msgspec.field(default_factory=dict)


class ErrorRecord(msgspec.Struct, frozen=True, kw_only=True):
    source: str
    """Module name, or ``ral``."""
    code: int
    stamp: float
    detail: str = ""


class GriState(msgspec.Struct, frozen=True, kw_only=True):
    """One robot as every ground station sees it; fields a robot does not know are ``None``."""

    robot: str
    kind: str = ""
    stamp: float
    position: GeoPoint | None = None
    attitude: Attitude | None = None
    velocity: VelocityNED | None = None
    heading_deg: float | None = None
    mode: int | None = None
    mode_name: str = ""
    airborne: bool | None = None
    waypoints_queued: int | None = None
    pan_deg: float | None = None
    tilt_deg: float | None = None
    home: GeoPoint | None = None
    """Take-off point (the ``return`` failsafe flies there)."""
    tasks: list[TaskInfo] = msgspec.field(default_factory=list)
    """The current task of each task type."""
    available: dict[str, str] = msgspec.field(default_factory=dict)
    """Manifest task name → task type: what this robot can do."""
    modules: list[ModuleHealth] = msgspec.field(default_factory=list)
    errors: list[ErrorRecord] = msgspec.field(default_factory=list)
    """Most recent errors, newest last (bounded)."""
    link: LinkState = "no_gcs"
    manager_up: bool = False
    """A Module Manager state arrived recently."""


EventKind = Literal[
    "task_accepted",
    "task_rejected",
    "task_completed",
    "task_cancelled",
    "task_replaced",
    "task_failed",
    "aborted",
    "link_up",
    "link_lost",
    "failsafe",
    "link_regained",
    "manager_lost",
    "manager_back",
]


class GriEvent(msgspec.Struct, frozen=True, kw_only=True):
    robot: str
    stamp: float
    kind: EventKind
    task_id: int = 0
    task_type: str = ""
    detail: str = ""


class GcsHeartbeat(msgspec.Struct, frozen=True, kw_only=True):
    gcs: str
    seq: int
    stamp: float


# ---------------------------------------------------------------- keys and codecs


def state_key(robot: str) -> str:
    return keys.ral_key(robot, STATE)


def events_key(robot: str) -> str:
    return keys.ral_key(robot, EVENTS)


def task_key(robot: str) -> str:
    return keys.ral_key(robot, TASK)


def gcs_alive_key(name: str = "*") -> str:
    return f"{keys.ROOT}/@gcs/{name if name == '*' else keys.validate_name(name, 'GCS name')}"


def gcs_heartbeat_key(name: str = "*") -> str:
    return f"{gcs_alive_key(name)}/heartbeat"


_request_decoder = msgspec.msgpack.Decoder(TaskRequest)
_reply_decoder = msgspec.msgpack.Decoder(TaskReply)
_state_decoder = msgspec.msgpack.Decoder(GriState)
_event_decoder = msgspec.msgpack.Decoder(GriEvent)
_heartbeat_decoder = msgspec.msgpack.Decoder(GcsHeartbeat)
_encoder = msgspec.msgpack.Encoder()


def encode(value: msgspec.Struct) -> bytes:
    return _encoder.encode(value)


def decode_request(payload: bytes) -> TaskRequest:
    """Decode = validate: msgspec.ValidationError says which field is wrong and why."""
    return _request_decoder.decode(payload)


def decode_reply(payload: bytes) -> TaskReply:
    return _reply_decoder.decode(payload)


def decode_state(payload: bytes) -> GriState:
    return _state_decoder.decode(payload)


def decode_event(payload: bytes) -> GriEvent:
    return _event_decoder.decode(payload)


def decode_heartbeat(payload: bytes) -> GcsHeartbeat:
    return _heartbeat_decoder.decode(payload)
