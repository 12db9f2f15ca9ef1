"""The shared environment model, pure (docs/world.md): entries, their deterministic merge, and what they forbid.

- :class:`WorldModel`: a last-writer-wins map (a state-based CRDT): per id, the greatest
  ``(version, origin, body bytes)`` wins, so any two RALs that received the same entries, in any order and any
  number of times, hold the same model (:meth:`WorldModel.digest`). A local edit takes the next version of its id.
- :func:`refusal`: why a task must not run given the model (a point inside, or a leg across, a no-fly zone; a
  point outside every geofence), or None.
- :func:`target_entry`: a vision target report → the robot's target entry, at most once per second or 2 m.
- :func:`check_edit` / :func:`entry_signer`: on a secured fleet, whether a zone entry or a removal was signed by a
  ground station the robot trusts (bbcs/signing.py); a robot's own entries need no signature.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable

import msgspec

from bbcs.contracts import tasks as t
from bbcs.contracts import world as w
from bbcs.contracts.geo import GeoPoint
from bbcs.signing import FleetTrust, SignatureRefused, authenticate
from ral import world_geometry as g

_encoder = msgspec.msgpack.Encoder(order="deterministic")
TARGET_MIN_PERIOD_S = 1.0
TARGET_MIN_MOVE_M = 2.0


def _rank(entry: w.WorldEntry) -> tuple[float, int, str, bytes]:
    """A station's zone or removal ranks by when the station signed it first (a replayed older edit never undoes a
    newer one, whatever version a RAL gave it); a robot's own entries (and every entry of an unsecured fleet,
    unsigned: 0) by version."""
    signed = 0.0 if entry.id.startswith(w.ROBOT_ENTRY_PREFIXES) else entry.signed_at
    return signed, entry.version, entry.origin, _encoder.encode(entry)


class WorldModel:
    """Every entry this RAL knows, tombstones included (a removal must keep beating the versions it removed)."""

    def __init__(self) -> None:
        self._entries: dict[str, w.WorldEntry] = {}

    def merge(self, entry: w.WorldEntry) -> bool:
        """Keep ``entry`` if it beats the one held under its id; True when the model changed."""
        held = self._entries.get(entry.id)
        if held is not None and _rank(held) >= _rank(entry):
            return False
        self._entries[entry.id] = entry
        return True

    def merge_all(self, entries: Iterable[w.WorldEntry]) -> list[w.WorldEntry]:
        """Merge several; the ones that changed the model."""
        return [e for e in entries if self.merge(e)]

    def put(self, entry_id: str, body: w.Body, *, origin: str, stamp: float, author: str = "",
            signer_cert: bytes = b"", signature: bytes = b"", signed_at: float = 0.0,
            valid_until: float = 0.0) -> w.WorldEntry:
        """A local write: the next version of ``entry_id`` (with the station's signature of the edit, if any)."""
        held = self._entries.get(entry_id)
        entry = w.WorldEntry(id=entry_id, version=(held.version if held else 0) + 1, origin=origin, stamp=stamp,
                             body=body, author=author or origin, signer_cert=signer_cert, signature=signature,
                             signed_at=signed_at, valid_until=valid_until)
        self.merge(entry)
        return entry

    def delete(self, entry_id: str, *, origin: str, stamp: float, author: str = "", signer_cert: bytes = b"",
               signature: bytes = b"", signed_at: float = 0.0, valid_until: float = 0.0) -> w.WorldEntry | None:
        """A local removal (a tombstone); None when there is nothing live under ``entry_id``."""
        held = self._entries.get(entry_id)
        if held is None or held.deleted:
            return None
        entry = w.WorldEntry(id=entry_id, version=held.version + 1, origin=origin, stamp=stamp, deleted=True,
                             author=author or origin, signer_cert=signer_cert, signature=signature,
                             signed_at=signed_at, valid_until=valid_until)
        self.merge(entry)
        return entry

    def held(self, entry_id: str) -> w.WorldEntry | None:
        """What is held under ``entry_id``, a tombstone included."""
        return self._entries.get(entry_id)

    def get(self, entry_id: str) -> w.WorldEntry | None:
        entry = self._entries.get(entry_id)
        return None if entry is None or entry.deleted else entry

    def entries(self, *, with_deleted: bool = False) -> list[w.WorldEntry]:
        return [e for _, e in sorted(self._entries.items()) if with_deleted or not e.deleted]

    def of_kind(self, kind: type) -> list[tuple[w.WorldEntry, object]]:
        return [(e, e.body) for e in self.entries() if isinstance(e.body, kind)]

    def digest(self) -> str:
        """Same on every RAL holding the same entries (tombstones included)."""
        h = hashlib.sha256()
        for entry in self.entries(with_deleted=True):
            h.update(_encoder.encode(entry))
        return h.hexdigest()[:16]

    def __len__(self) -> int:
        return len(self._entries)


# ---------------------------------------------------------------- what the model forbids


def _places(task: t.TaskParams) -> tuple[list[tuple[str, float, float]], list[tuple[float, float]] | None]:
    """(labelled points the task sends the robot to, an area it covers or None)."""
    if isinstance(task, t.Goto | t.FollowPath):
        return [(f"waypoint {i} ({p.lat:.6f}, {p.lon:.6f})", p.lat, p.lon) for i, p in enumerate(task.waypoints)], None
    if isinstance(task, t.Survey):
        return [], [(v.lat, v.lon) for v in task.polygon]
    if isinstance(task, t.Orbit):
        return [], g.circle(task.lat, task.lon, task.radius)
    return [], None


def _zone_name(entry: w.WorldEntry, body: w.NoFlyZone | w.Geofence) -> str:
    label = f"{entry.id!r}" + (f" ({body.name})" if body.name and body.name != entry.id else "")
    return f"{label}, set by {entry.author or entry.origin} via {entry.origin}"


def refusal(model: WorldModel, task: t.TaskParams, position: GeoPoint | None = None) -> str | None:
    """Why ``task`` must not run in this world (None: nothing in the model forbids it). A movement leg from the
    robot's ``position`` to the first waypoint counts too, unless the robot is inside that zone already (it may
    leave; it may not go deeper to a waypoint inside)."""
    points, area = _places(task)
    if not points and area is None:
        return None
    lat0, lon0 = (points[0][1], points[0][2]) if points else area[0]  # type: ignore[index]
    xy = g.project([(lat, lon) for _, lat, lon in points], lat0, lon0)
    area_xy = g.project(area, lat0, lon0) if area is not None else None
    kind = t.kind_of(task)
    for entry, body in model.of_kind(w.NoFlyZone):
        assert isinstance(body, w.NoFlyZone)
        zone = g.project([(v.lat, v.lon) for v in body.polygon], lat0, lon0)
        for (label, _, _), p in zip(points, xy, strict=True):
            if g.inside(p, zone):
                return f"{kind}: {label} is inside no-fly zone {_zone_name(entry, body)}"
        legs = list(zip(xy, xy[1:], strict=False))
        labels = [f"the leg from waypoint {i} to waypoint {i + 1}" for i in range(len(legs))]
        if position is not None and xy:
            here = g.project([(position.lat, position.lon)], lat0, lon0)[0]
            if not g.inside(here, zone):  # a robot caught inside a new zone may still leave it
                legs.insert(0, (here, xy[0]))
                labels.insert(0, "the leg from the robot's position to waypoint 0")
        for label, (a, b) in zip(labels, legs, strict=True):
            if g.leg_enters(a, b, zone):
                return f"{kind}: {label} crosses no-fly zone {_zone_name(entry, body)}"
        if area_xy is not None and g.polygons_overlap(area_xy, zone):
            return f"{kind}: the area overlaps no-fly zone {_zone_name(entry, body)}"
    fences = model.of_kind(w.Geofence)
    if fences:
        shapes = [g.project([(v.lat, v.lon) for v in body.polygon], lat0, lon0) for _, body in fences]  # type: ignore[attr-defined]
        names = ", ".join(repr(e.id) for e, _ in fences)
        for (label, _, _), p in zip(points, xy, strict=True):
            if not any(g.inside(p, s) for s in shapes):
                return f"{kind}: {label} is outside every geofence of the fleet ({names})"
        for v in area_xy or []:
            if not any(g.inside(v, s) for s in shapes):
                return f"{kind}: the area reaches outside every geofence of the fleet ({names})"
    return None


# ---------------------------------------------------------------- signed edits (secured fleets)


class ReservedId(SignatureRefused):
    """A zone under an id of the robots' own entries (``target.*``, ``surveyed.*``), which any robot may write."""


def check_edit(edit: w.StationEdit, trust: FleetTrust, now: float) -> str:
    """The CN of the ground station that signed ``edit`` if a secured robot may apply it at ``now``; else raises
    :class:`~bbcs.signing.SignatureRefused` (:class:`ReservedId`, or why the signature does not hold). The edit's
    own validity window is the caller's (:func:`bbcs.signing.check_window`: a station's request must be within it,
    an entry already in the fleet's model need not)."""
    if not edit.remove and edit.id.startswith(w.ROBOT_ENTRY_PREFIXES):
        raise ReservedId(f"{edit.id!r} is the id of a robot's own entry ({', '.join(w.ROBOT_ENTRY_PREFIXES)}...)")
    return authenticate(edit, trust, now)


def entry_signer(entry: w.WorldEntry, trust: FleetTrust, now: float) -> str | None:
    """Whether a secured robot may merge ``entry``: None for a robot's own entry (a live vision target or surveyed
    area under its id: not signed), the signing station's CN for a zone or a removal; raises
    :class:`~bbcs.signing.SignatureRefused` otherwise."""
    edit = w.edit_of_entry(entry)
    return None if edit is None else check_edit(edit, trust, now)


# ---------------------------------------------------------------- vision targets


def target_id(robot: str) -> str:
    """One target entry per robot's vision (its tracker follows one target)."""
    return f"target.{robot}"


def target_entry(held: w.WorldEntry | None, *, lat: float, lon: float, alt: float, robot: str,
                 now: float) -> w.Target | None:
    """The new body of ``robot``'s target entry from a vision report, or None when the held one is recent and
    close enough (the bus gets at most one update per second unless the target moved more than 2 m)."""
    if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)):
        return None
    body = held.body if held is not None else None
    if isinstance(body, w.Target):
        moved = g.project([(lat, lon)], body.lat, body.lon)[0]
        if now - body.seen_at < TARGET_MIN_PERIOD_S and math.hypot(*moved) < TARGET_MIN_MOVE_M:
            return None
    return w.Target(lat=lat, lon=lon, alt=alt, seen_by=robot, seen_at=now)


def surveyed_entry(task: t.TaskInfo, robot: str, now: float) -> tuple[str, w.Surveyed] | None:
    """A completed survey task → (entry id, its surveyed area); None for any other task."""
    if task.status != "completed" or not isinstance(task.params, t.Survey):
        return None
    return f"surveyed.{robot}.{task.id}", w.Surveyed(polygon=list(task.params.polygon), by=robot, at=now)
