"""The bus side of the world model (docs/world.md): a thin adapter around the pure :mod:`ral.world`.

A :class:`WorldNode` in every RAL:
- holds a :class:`~ral.world.WorldModel`; on start asks every RAL on the mesh for its whole model (wildcard query
  of ``@ral/world_model``) after subscribing to their updates, so a late joiner misses nothing;
- publishes what it changes on ``@ral/world`` and merges what the others publish;
- answers ground stations on ``@ral/world_request``: add / remove an entry, track a target of the model (a
  ``look_at`` task whose point follows the entry as whoever saw it updates it);
- turns its own robot's vision target (``vision/target``) into the robot's target entry, and its completed
  survey tasks (from the manager's task book) into surveyed areas;
- every ``digest_period_s`` publishes a digest of what it holds; a RAL that hears a different digest asks that
  peer's model again (anti-entropy: updates lost in a partition are recovered when it heals);
- on a secured robot (``trust``), applies or merges a zone entry or a removal, from a station's request, a peer's
  update or a peer's snapshot, only if a ground station signed it (:func:`ral.world.entry_signer`); anything else
  is dropped, counted by reason (``gate.refused``) and logged once, so it is never applied nor relayed in this
  RAL's snapshots. The robots' own entries (vision targets, surveyed areas) are not signed.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh

from bbcs import keys, wire
from bbcs.contracts import gri, mri
from bbcs.contracts import tasks as t
from bbcs.contracts import world as w
from bbcs.contracts.pan_tilt import DatosPT
from bbcs.contracts.signed import seal_of
from bbcs.signing import FleetTrust
from ral import world
from ral.signed import SignatureGate

log = logging.getLogger(__name__)
DIGEST_PERIOD_S = 2.0
QUERY_TIMEOUT_S = 3.0

_update_decoder = msgspec.msgpack.Decoder(w.WorldUpdate)
_digest_decoder = msgspec.msgpack.Decoder(w.WorldDigest)
_snapshot_decoder = msgspec.msgpack.Decoder(w.WorldSnapshot)
_request_decoder = msgspec.msgpack.Decoder(w.WorldRequest)
_datos_decoder = msgspec.msgpack.Decoder(DatosPT)
_state_decoder = msgspec.msgpack.Decoder(mri.RobotState)
_encoder = msgspec.msgpack.Encoder()


def fetch_snapshots(session: zenoh.Session, robot: str = "*",
                    timeout_s: float = QUERY_TIMEOUT_S) -> list[w.WorldSnapshot]:
    """The whole model of ``robot``'s RAL (``*``: of every RAL that answers)."""
    out = []
    for reply in session.get(w.world_model_key(robot), timeout=timeout_s):
        if reply.ok is None:
            continue
        try:
            out.append(_snapshot_decoder.decode(reply.ok.payload.to_bytes()))
        except msgspec.MsgspecError:
            continue
    return out


class WorldNode:
    def __init__(self, session: zenoh.Session, robot: str, clock: Callable[[], float], *,
                 digest_period_s: float = DIGEST_PERIOD_S,
                 on_change: Callable[[list[w.WorldEntry]], None] | None = None,
                 start_task: Callable[[t.TaskParams], gri.TaskReply] | None = None,
                 point_at: Callable[[w.Target, int], bool] | None = None,
                 trust: FleetTrust | None = None, trust_clock: Callable[[], float] = time.time) -> None:
        """``start_task``: the RAL's own ``handle`` (for track_target's look_at); ``point_at(target, task_id)``:
        send the pan & tilt a new point if task ``task_id`` still runs (False: it ended, stop following);
        ``trust``: a secured robot's (the fleet tasks' trust), checked at ``trust_clock``'s time (certificates'
        dates are wall-clock ones)."""
        self.session = session
        self.gate = SignatureGate(trust, trust_clock, "world edit", check=world.check_edit,  # type: ignore[arg-type]
                                  logger=log)
        self._gate_lock = threading.Lock()
        self.start_task = start_task
        self.point_at = point_at
        self._tracking: tuple[str, int] | None = None
        self.robot = robot
        self.clock = clock
        self.model = world.WorldModel()
        self.lock = threading.Lock()
        self.on_change = on_change
        self._stop = threading.Event()
        self._resync: set[str] = set()
        self._wake = threading.Condition()
        self._pub = session.declare_publisher(
            w.world_key(robot), encoding=wire.encoding_for(w.WorldUpdate),
            reliability=zenoh.Reliability.RELIABLE, congestion_control=zenoh.CongestionControl.BLOCK)
        self._digest_pub = session.declare_publisher(w.world_digest_key(robot),
                                                     encoding=wire.encoding_for(w.WorldDigest))
        self._entities: list[Any] = [
            session.declare_subscriber(w.world_key("*"), self._on_update),
            session.declare_subscriber(w.world_digest_key("*"), self._on_digest),
            session.declare_subscriber(keys.slot_key(robot, "vision", "target"), self._on_vision_target),
            session.declare_subscriber(mri.mri_key(robot, mri.STATE), self._on_manager_state),
            session.declare_queryable(w.world_model_key(robot), self._on_model_query),
            session.declare_queryable(w.world_request_key(robot), self._on_request),
        ]
        self._thread = threading.Thread(target=self._run, name="ral.world", daemon=True)
        self._digest_period_s = digest_period_s
        self._thread.start()

    # ------------------------------------------------------------ merging

    def _admitted(self, entries: list[w.WorldEntry], source: str) -> list[w.WorldEntry]:
        """The entries a secured robot may merge (all of them on an unsecured one)."""
        if self.gate.trust is None:
            return entries
        out = []
        with self._gate_lock:
            for entry in entries:
                edit = w.edit_of_entry(entry)
                label = f"{'removal of' if entry.deleted else 'entry'} {entry.id!r} v{entry.version}"
                if edit is None or self.gate.admit(edit, source, label, expiry=False):
                    out.append(entry)
        return out

    def _merge(self, entries: list[w.WorldEntry]) -> list[w.WorldEntry]:
        with self.lock:
            changed = self.model.merge_all(entries)
        if changed:
            self._changed(changed)
        return changed

    def _publish(self, entries: list[w.WorldEntry]) -> None:
        if entries:
            self._pub.put(_encoder.encode(w.WorldUpdate(robot=self.robot, entries=entries)))
            self._changed(entries)

    def _changed(self, entries: list[w.WorldEntry]) -> None:
        if self.on_change is not None:
            self.on_change(entries)
        tracking = self._tracking
        if tracking is None or self.point_at is None:
            return
        for entry in entries:
            if entry.id == tracking[0] and isinstance(entry.body, w.Target):
                if not self.point_at(entry.body, tracking[1]):
                    self._tracking = None

    def _on_update(self, sample: zenoh.Sample) -> None:
        try:
            update = _update_decoder.decode(sample.payload.to_bytes())
        except msgspec.MsgspecError as exc:
            log.warning("unreadable world update on %s dropped: %s", sample.key_expr, exc)
            return
        if update.robot != self.robot:
            self._merge(self._admitted(update.entries, f"the update on {sample.key_expr}"))

    def _on_digest(self, sample: zenoh.Sample) -> None:
        try:
            digest = _digest_decoder.decode(sample.payload.to_bytes())
        except msgspec.MsgspecError:
            return
        if digest.robot == self.robot:
            return
        with self.lock:
            same = digest.digest == self.model.digest()
        if not same:
            with self._wake:
                self._resync.add(digest.robot)
                self._wake.notify_all()

    def _on_model_query(self, query: zenoh.Query) -> None:
        wire.reply(query, w.world_model_key(self.robot), self.snapshot())

    def snapshot(self) -> w.WorldSnapshot:
        with self.lock:
            return w.WorldSnapshot(robot=self.robot, digest=self.model.digest(),
                                   entries=self.model.entries(with_deleted=True))

    # ------------------------------------------------------------ local writes

    def request(self, request: w.WorldRequest) -> w.WorldReply:
        """A ground station's request: an edit (applied here and published to every RAL) or a tracking."""
        if isinstance(request, w.StopTracking):
            self._tracking = None
            return w.WorldReply(accepted=True)
        if isinstance(request, w.TrackTarget):
            return self._track(request.target)
        return self.edit(request)

    def _track(self, target_id: str) -> w.WorldReply:
        entry = self.get(target_id)
        if entry is None or not isinstance(entry.body, w.Target):
            with self.lock:
                known = [e.id for e, _ in self.model.of_kind(w.Target)]
            return w.WorldReply(accepted=False, reason=f"no target {target_id!r} in the world model "
                                                       f"(targets: {', '.join(known) or 'none'})")
        if self.start_task is None:
            return w.WorldReply(accepted=False, reason="this RAL cannot start tasks")
        body = entry.body
        self._tracking = None
        reply = self.start_task(t.LookAt(lat=body.lat, lon=body.lon, alt=body.alt))
        if not reply.accepted:
            return w.WorldReply(accepted=False, reason=f"look_at at {target_id!r} refused: {reply.reason}",
                                entry=entry)
        self._tracking = (target_id, reply.task_id)
        latest = self.get(target_id)  # it may have moved while the task started
        if latest is not None and latest != entry and isinstance(latest.body, w.Target) and self.point_at:
            self.point_at(latest.body, reply.task_id)
        return w.WorldReply(accepted=True, entry=entry, task_id=reply.task_id)

    def edit(self, edit: w.WorldPut | w.WorldDelete) -> w.WorldReply:
        """A ground station's edit, applied here and published to every RAL (on a secured robot only if the
        station signed it: nothing changes otherwise)."""
        signed = w.edit_of_request(edit)
        if self.gate.trust is not None and signed is not None:
            kind = ("removal of" if isinstance(edit, w.WorldDelete)
                    else "zone" if isinstance(edit.body, w.NoFlyZone | w.Geofence) else "entry")
            what = f"{kind} {edit.id!r}"
            with self._gate_lock:
                why = self.gate.refusal(signed, "a ground station's request", what)
            if why is not None:
                return w.WorldReply(accepted=False, reason=f"{what} not applied: {why} (this robot applies only "
                                                           f"edits signed by its ground stations)")
        now = self.clock()
        sig = seal_of(edit)
        with self.lock:
            held = self.model.held(edit.id)
            if self.gate.trust is not None and signed is not None and held is not None and held.signed_at > 0:
                with self._gate_lock:  # a replayed older edit must not undo a newer one (ral/world.py _rank)
                    why = self.gate.stale(signed, held.signed_at, "edit of this entry", "a ground station's request",
                                          f"edit of {edit.id!r}")
                if why is not None:
                    return w.WorldReply(accepted=False, reason=f"edit of {edit.id!r} not applied: {why}")
            if isinstance(edit, w.WorldPut):
                entry: w.WorldEntry | None = self.model.put(edit.id, edit.body, origin=self.robot, stamp=now,
                                                           author=edit.author, **sig)
            else:
                entry = self.model.delete(edit.id, origin=self.robot, stamp=now, author=edit.author, **sig)
        if entry is None:
            return w.WorldReply(accepted=False, reason=f"no world entry {edit.id!r} to remove")
        self._publish([entry])
        return w.WorldReply(accepted=True, entry=entry)

    def _on_request(self, query: zenoh.Query) -> None:
        """Answered on a thread of its own: a track_target starts a task (MRI round trips), too slow for Zenoh's."""
        wire.answer_in_thread(query, w.world_request_key(self.robot), _request_decoder, self.request,
                              lambda why: w.WorldReply(accepted=False, reason=f"invalid world request: {why}"),
                              "ral.world_request")

    def _on_vision_target(self, sample: zenoh.Sample) -> None:
        try:
            datum = _datos_decoder.decode(sample.payload.to_bytes())
        except msgspec.MsgspecError:
            return
        entry_id = world.target_id(self.robot)
        now = self.clock()
        with self.lock:
            body = world.target_entry(self.model.get(entry_id), lat=datum.latitud, lon=datum.longitud,
                                      alt=datum.altura, robot=self.robot, now=now)
            entry = self.model.put(entry_id, body, origin=self.robot, stamp=now) if body is not None else None
        if entry is not None:
            self._publish([entry])

    def _on_manager_state(self, sample: zenoh.Sample) -> None:
        try:
            state = _state_decoder.decode(sample.payload.to_bytes())
        except msgspec.MsgspecError:
            return
        fresh = []
        now = self.clock()
        with self.lock:
            for info in state.ended:
                found = world.surveyed_entry(info, self.robot, now)
                if found is not None and found[0] not in {e.id for e in self.model.entries(with_deleted=True)}:
                    fresh.append(self.model.put(found[0], found[1], origin=self.robot, stamp=now))
        self._publish(fresh)

    # ------------------------------------------------------------ queries

    def refusal(self, task: Any, position: Any = None) -> str | None:
        with self.lock:
            return world.refusal(self.model, task, position)

    def get(self, entry_id: str) -> w.WorldEntry | None:
        with self.lock:
            return self.model.get(entry_id)

    # ------------------------------------------------------------ catch-up and anti-entropy

    def _run(self) -> None:
        self._catch_up("*")
        while not self._stop.is_set():
            with self._wake:
                self._wake.wait_for(lambda: self._resync or self._stop.is_set(), timeout=self._digest_period_s)
                peers, self._resync = sorted(self._resync), set()
            if self._stop.is_set():
                return
            for peer in peers:
                self._catch_up(peer)
            with self.lock:
                digest = w.WorldDigest(robot=self.robot, digest=self.model.digest(), entries=len(self.model))
            try:
                self._digest_pub.put(_encoder.encode(digest))
            except Exception:
                return

    def _catch_up(self, robot: str) -> None:
        try:
            snapshots = fetch_snapshots(self.session, robot)
        except Exception:  # the session closing under us
            return
        for snap in snapshots:
            if snap.robot != self.robot:
                self._merge(self._admitted(snap.entries, f"{snap.robot}'s snapshot"))

    def close(self) -> None:
        self._stop.set()
        with self._wake:
            self._wake.notify_all()
        self._thread.join(1.0)  # a daemon: a catch-up query still waiting gives up on the closed session
        for entity in reversed(self._entities):
            entity.undeclare()
        self._digest_pub.undeclare()
        self._pub.undeclare()
