"""The shared environment model (issue 17, docs/world.md): entries every RAL holds and merges.

| key | what |
| --- | --- |
| ``cromat/<robot>/@ral/world``        | :class:`WorldUpdate`, safe stream: entries this RAL changed or learnt |
| ``cromat/<robot>/@ral/world_digest`` | :class:`WorldDigest`, every few seconds: what this RAL holds (anti-entropy) |
| ``cromat/<robot>/@ral/world_model``  | queryable: the whole model as a :class:`WorldSnapshot` (late joiners) |
| ``cromat/<robot>/@ral/world_request`` | queryable: a :data:`WorldRequest` in, a :class:`WorldReply` out (GCS) |

An entry is identified by ``id``; of two entries with one id the greater ``(version, origin, body bytes)`` wins
everywhere (last-writer-wins register per id: merging is commutative, associative and idempotent). A removal is
an entry with ``deleted`` set (a tombstone), so it wins over the older versions it replaces.

On a secured fleet a ground station signs each edit it asks for (:class:`StationEdit`, bbcs/signing.py): the
request and every entry it becomes carry the station's certificate and signature, so any robot can check a zone
or a removal however it arrived (a station's request, a peer's update, a peer's snapshot). The entries robots
write themselves (:data:`ROBOT_ENTRY_PREFIXES`: vision targets, surveyed areas) are not signed.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from bbcs import keys
from bbcs.contracts.geo import AltitudeAMSL, Latitude, Longitude
from bbcs.contracts.signed import Signature, SignerCert, seal_of
from bbcs.contracts.tasks import Vertex

WORLD = "world"
WORLD_DIGEST = "world_digest"
WORLD_MODEL = "world_model"
WORLD_REQUEST = "world_request"

Polygon = Annotated[list[Vertex], msgspec.Meta(min_length=3, max_length=500)]
"""WGS84 corners, not closed (the last joins the first)."""
EntryId = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}$")]


class NoFlyZone(msgspec.Struct, frozen=True, kw_only=True, tag="no_fly_zone"):
    """No robot may be sent inside ``polygon`` or across it, at any height."""

    polygon: Polygon
    name: str = ""


class Geofence(msgspec.Struct, frozen=True, kw_only=True, tag="geofence"):
    """Keep-in area: with any geofence in the model, every point a robot is sent to lies inside one."""

    polygon: Polygon
    name: str = ""


class Target(msgspec.Struct, frozen=True, kw_only=True, tag="target"):
    """A target a robot's vision geolocated."""

    lat: Latitude
    lon: Longitude
    alt: AltitudeAMSL
    seen_by: str
    seen_at: float
    """The seeing robot's sync clock (docs/sync.md) when its vision reported it."""


class Surveyed(msgspec.Struct, frozen=True, kw_only=True, tag="surveyed"):
    """An area a robot's survey task completed over."""

    polygon: Polygon
    by: str
    at: float


Body = NoFlyZone | Geofence | Target | Surveyed


class WorldEntry(msgspec.Struct, frozen=True, kw_only=True):
    id: EntryId
    version: Annotated[int, msgspec.Meta(ge=1)]
    origin: str
    """The robot whose RAL wrote this version."""
    stamp: float
    """That RAL's sync clock when it wrote it."""
    body: Body | None = None
    """``None`` on a removal (``deleted``)."""
    deleted: bool = False
    author: str = ""
    """Who asked for it (a ground station's name, or the robot itself): a label, not checked (the signer is)."""
    signed_at: float = 0.0
    """When the ground station signed this edit (its clock); a newer signed edit of an id wins (ral/world.py)."""
    valid_until: float = 0.0
    signer_cert: SignerCert = b""
    """The certificate (DER) of the ground station that signed this edit (:func:`edit_of_entry`); empty: unsigned
    (an unsecured fleet, or a robot's own entry)."""
    signature: Signature = b""


class WorldUpdate(msgspec.Struct, frozen=True, kw_only=True):
    robot: str
    entries: list[WorldEntry]


class WorldDigest(msgspec.Struct, frozen=True, kw_only=True):
    robot: str
    digest: str
    entries: int


class WorldSnapshot(msgspec.Struct, frozen=True, kw_only=True):
    robot: str
    digest: str
    entries: list[WorldEntry] = msgspec.field(default_factory=list)


class WorldPut(msgspec.Struct, frozen=True, kw_only=True, tag="put"):
    id: EntryId
    body: Body
    author: str = ""
    signed_at: float = 0.0
    valid_until: float = 0.0
    signer_cert: SignerCert = b""
    """A station with a TLS identity signs :func:`edit_of_request` (``cromat gcs world`` does)."""
    signature: Signature = b""


class WorldDelete(msgspec.Struct, frozen=True, kw_only=True, tag="delete"):
    id: EntryId
    author: str = ""
    signed_at: float = 0.0
    valid_until: float = 0.0
    signer_cert: SignerCert = b""
    signature: Signature = b""


ROBOT_ENTRY_PREFIXES = ("target.", "surveyed.")
"""Ids of the entries robots write themselves, unsigned: a vision target (``target.<robot>``), a surveyed area
(``surveyed.<robot>.<task>``). A zone under such an id would be one a robot could overwrite, so none is admitted."""


class StationEdit(msgspec.Struct, frozen=True, kw_only=True):
    """What a ground station signs for an edit of the world model: the entry ``id``, and either its new ``body``
    (a no-fly zone or geofence: its kind, polygon and name) or its removal (``remove``, ``body`` None), with when
    it was signed and until when a robot may apply the request (``signed_at``, ``valid_until``). Never sent on its
    own: rebuilt from the request or entry that carries the signature."""

    id: EntryId
    remove: bool
    body: Body | None = None
    signed_at: float = 0.0
    valid_until: float = 0.0
    signer_cert: SignerCert = b""
    signature: Signature = b""


def robot_entry(entry_id: str, body: Body | None, deleted: bool) -> bool:
    """A live vision target or surveyed area under a robot's own id: written by a RAL, not signed by a station."""
    return not deleted and isinstance(body, Target | Surveyed) and entry_id.startswith(ROBOT_ENTRY_PREFIXES)


def edit_of_entry(entry: WorldEntry) -> StationEdit | None:
    """The signed edit ``entry`` must carry on a secured fleet; None for a robot's own entry."""
    if robot_entry(entry.id, entry.body, entry.deleted):
        return None
    return StationEdit(id=entry.id, remove=entry.deleted, body=None if entry.deleted else entry.body,
                       **seal_of(entry))


def edit_of_request(request: WorldPut | WorldDelete) -> StationEdit | None:
    """What a station signs for ``request`` (and a secured RAL checks); None for a robot's own kind of entry."""
    if isinstance(request, WorldDelete):
        return StationEdit(id=request.id, remove=True, **seal_of(request))
    if robot_entry(request.id, request.body, False):
        return None
    return StationEdit(id=request.id, remove=False, body=request.body, **seal_of(request))


class TrackTarget(msgspec.Struct, frozen=True, kw_only=True, tag="track_target"):
    """Point this robot's pan & tilt at a target of the model, whoever saw it, and keep pointing as it moves
    (a ``look_at`` task whose point follows the entry)."""

    target: EntryId


class StopTracking(msgspec.Struct, frozen=True, kw_only=True, tag="stop_tracking"):
    """Stop following a target entry (the pan & tilt task is left as it is)."""


WorldRequest = WorldPut | WorldDelete | TrackTarget | StopTracking


class WorldReply(msgspec.Struct, frozen=True, kw_only=True):
    accepted: bool
    reason: str = ""
    entry: WorldEntry | None = None
    task_id: int = 0
    """For a track_target: the look_at task started."""


def world_key(robot: str) -> str:
    return keys.ral_key(robot, WORLD)


def world_digest_key(robot: str) -> str:
    return keys.ral_key(robot, WORLD_DIGEST)


def world_model_key(robot: str) -> str:
    return keys.ral_key(robot, WORLD_MODEL)


def world_request_key(robot: str) -> str:
    return keys.ral_key(robot, WORLD_REQUEST)
