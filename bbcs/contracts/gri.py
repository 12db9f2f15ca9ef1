"""The GRI (General Robot Interface): what every robot shows ground stations and other robots.

| key | what |
| --- | --- |
| ``cromat/<robot>/@ral/state``  | :class:`GriState`, safe state (a late joiner gets the last one) |
| ``cromat/<robot>/@ral/events`` | :class:`GriEvent`, safe stream |
| ``cromat/<robot>/@ral/task``   | queryable: a :data:`TaskRequest` (msgpack) in, a :class:`TaskReply` out |
| ``cromat/@gcs/<name>``         | liveliness token of a ground station |
| ``cromat/@gcs/<name>/heartbeat`` | :class:`GcsHeartbeat`: the robots that station holds a link with |

The link is per robot: a station's token counts for a robot only while its heartbeats name that robot.

Task requests are one tagged union; ranges live in the types, so a request that decodes is a valid request
(waypoint out of range, unknown task tag: refused at decoding with msgspec's message).
"""

from __future__ import annotations

from typing import Literal

import msgspec

from bbcs import bounded, keys
from bbcs.contracts.mri import ErrorEvent, ModuleStatus
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.contracts.tasks import (
    MAX_WAYPOINTS,
    TASK_KINDS,
    AltitudeAMSL,
    Bridge,
    FollowPath,
    FollowVisionPath,
    Goto,
    HeightAboveHome,
    Hold,
    Land,
    Latitude,
    Longitude,
    LookAt,
    Manual,
    Orbit,
    SetPanTilt,
    Speed,
    Survey,
    TakeOff,
    TaskInfo,
    TaskParams,
    TaskStatus,
    Track,
    Vertex,
    Waypoint,
    Waypoints,
    kind_of,
)

STATE = "state"
EVENTS = "events"
TASK = "task"


class Abort(msgspec.Struct, frozen=True, kw_only=True, tag="abort"):
    """Stop every running task now (both waypoint queues emptied, the robot holds); never queued."""


class Cancel(msgspec.Struct, frozen=True, kw_only=True, tag="cancel"):
    """End the running task of one type (``movement``, ``pan_tilt``, ... as the manifest names them)."""

    task_type: str


class RestartModule(msgspec.Struct, frozen=True, kw_only=True, tag="restart_module"):
    """Restart one module of the robot (its running tasks that need it fail with that reason)."""

    module: str


Task = TaskParams
"""Tasks that occupy a task type until completed, replaced, cancelled, aborted or failed."""
TaskRequest = TaskParams | Abort | Cancel | RestartModule
"""What a ground station may ask on ``@ral/task``: every task (declared once, :data:`bbcs.contracts.tasks.TaskParams`)
and the three requests that are not tasks."""
__all__ = [
    "MAX_WAYPOINTS", "TASK_KINDS", "AltitudeAMSL", "Bridge", "FollowPath", "FollowVisionPath", "Goto",
    "HeightAboveHome", "Hold", "Land", "Latitude", "LookAt", "Longitude", "Orbit", "SetPanTilt", "Speed", "Survey",
    "TakeOff", "Vertex",
    "TaskInfo", "TaskStatus", "Track", "Manual", "Waypoint", "Waypoints", "kind_of", "Abort", "Cancel", "RestartModule",
    "Task", "TaskRequest", "TaskReply", "GriState", "GriEvent", "GcsHeartbeat", "ModuleHealth", "ErrorRecord",
    "LinkState", "EventKind", "state_key", "events_key", "task_key", "gcs_alive_key", "gcs_heartbeat_key",
    "encode", "decode_request", "decode_reply", "decode_state", "decode_event", "decode_heartbeat",
]


class TaskReply(msgspec.Struct, frozen=True, kw_only=True):
    accepted: bool
    reason: str = ""
    """Why it was rejected (empty when accepted)."""
    task_id: int = 0
    task_type: str = ""
    code: int | None = None
    """The refusing module's error code, when a module refused it."""


# ---------------------------------------------------------------- state and events

LinkState = Literal["no_gcs", "up", "lost", "failsafe"]
ModuleHealth = ModuleStatus
"""A module's health as the Module Manager reports it (one shape for the MRI and the GRI)."""
ErrorRecord = ErrorEvent
"""One error: source module (or ``ral``), code, its name and detail."""


class GriState(msgspec.Struct, frozen=True, kw_only=True):
    """One robot as every ground station sees it; what a robot does not know is ``None``."""

    robot: str
    kind: str = ""
    stamp: float
    telemetry: RobotTelemetry | None = None
    """The robot's telemetry as its telemetry module publishes it (altitudes above mean sea level)."""
    home: GeoPoint | None = None
    """Take-off point (the ``return`` failsafe flies there; heights above home are measured from it)."""
    tasks: list[TaskInfo] = msgspec.field(default_factory=list)
    """The current task of each task type, whoever started it (the Module Manager's task book)."""
    available: dict[str, str] = msgspec.field(default_factory=dict)
    """Task kind → task type: what a ground station can send to this robot."""
    modules: list[ModuleStatus] = msgspec.field(default_factory=list)
    errors: list[ErrorEvent] = msgspec.field(default_factory=list)
    """Most recent errors, newest last (bounded)."""
    link: LinkState = "no_gcs"
    manager_up: bool = False
    """A Module Manager state arrived recently."""

    # views of the telemetry (not encoded: the telemetry is the one copy)
    @property
    def position(self) -> GeoPoint | None:
        return self.telemetry.position if self.telemetry else None

    @property
    def airborne(self) -> bool | None:
        return self.telemetry.airborne if self.telemetry else None

    @property
    def waypoints_queued(self) -> int | None:
        return self.telemetry.waypoints_queued if self.telemetry else None

    @property
    def pan_deg(self) -> float | None:
        return self.telemetry.pan_deg if self.telemetry else None

    @property
    def tilt_deg(self) -> float | None:
        return self.telemetry.tilt_deg if self.telemetry else None

    @property
    def mode(self) -> int | None:
        return self.telemetry.mode if self.telemetry else None

    @property
    def heading_deg(self) -> float | None:
        return self.telemetry.heading_deg if self.telemetry else None


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
    "module_restarted",
    "param_changed",
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
    robots: list[str] = msgspec.field(default_factory=list)
    """The robots this station holds a link with: a robot's RAL counts the station only if it is named here."""


# ---------------------------------------------------------------- keys and codecs


def state_key(robot: str) -> str:
    return keys.ral_key(robot, STATE)


def events_key(robot: str) -> str:
    return keys.ral_key(robot, EVENTS)


def task_key(robot: str) -> str:
    return keys.ral_key(robot, TASK)


def gcs_alive_key(name: str = "*") -> str:
    return keys.gcs_key(name)


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
    """Decode = validate: msgspec.ValidationError says which field is wrong and why; a request too large or too
    deeply nested is refused before decoding (bbcs.bounded.RequestRefused, a msgspec.DecodeError)."""
    return bounded.decode(_request_decoder, payload)


def decode_reply(payload: bytes) -> TaskReply:
    return _reply_decoder.decode(payload)


def decode_state(payload: bytes) -> GriState:
    return _state_decoder.decode(payload)


def decode_event(payload: bytes) -> GriEvent:
    return _event_decoder.decode(payload)


def decode_heartbeat(payload: bytes) -> GcsHeartbeat:
    return _heartbeat_decoder.decode(payload)
