"""The bus side of fleet time (docs/sync.md): a thin adapter around the pure :mod:`ral.sync`.

- :class:`ClockService`: the robot's ``@ral/clock`` queryable; stamps a probe on arrival (t2) and on answer (t3).
- :class:`ClockTracker`: a thread that probes every other RAL on the mesh (found by their liveliness tokens),
  feeds the samples to an :class:`~ral.sync.OffsetEstimator` and publishes the per-peer offsets
  (``@ral/clock_offsets``).
- :class:`SyncNode`: the ``@ral/sync`` queryable (synchronised start, formation keep) in a RAL; the RAL hands it
  a way to start a task (its own ``handle``) and to check one.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh
import zenoh.ext

from bbcs import bounded, keys, wire
from bbcs.contracts import gri
from bbcs.contracts import sync as s
from bbcs.contracts import tasks as t
from ral import sync

log = logging.getLogger(__name__)
PROBE_PERIOD_S = 0.5
PROBE_TIMEOUT_S = 1.0

_probe_decoder = msgspec.msgpack.Decoder(s.ClockProbe)
_echo_decoder = msgspec.msgpack.Decoder(s.ClockEcho)
_request_decoder = msgspec.msgpack.Decoder(s.SyncRequest)
_encoder = msgspec.msgpack.Encoder()


class ClockService:
    """Answers clock probes with this robot's clock (the sync clock, which tests may skew)."""

    def __init__(self, session: zenoh.Session, robot: str, clock: Callable[[], float]) -> None:
        self.robot = robot
        self.clock = clock
        self._key = s.clock_key(robot)
        self._queryable = session.declare_queryable(self._key, self._on_probe)

    def _on_probe(self, query: zenoh.Query) -> None:
        t2 = self.clock()
        try:
            probe = bounded.decode(_probe_decoder, query.payload.to_bytes() if query.payload is not None else b"")
        except msgspec.MsgspecError:
            return  # not a probe: no answer (the asker times out)
        echo = s.ClockEcho(robot=self.robot, t1=probe.t1, t2=t2, t3=self.clock())
        wire.reply(query, self._key, echo)

    def close(self) -> None:
        self._queryable.undeclare()


def probe(session: zenoh.Session, peer: str, clock: Callable[[], float],
          timeout_s: float = PROBE_TIMEOUT_S) -> sync.ClockSample | None:
    """One four-timestamp exchange with ``peer``'s clock service (None: no answer)."""
    t1 = clock()
    for reply in session.get(s.clock_key(peer), payload=_encoder.encode(s.ClockProbe(t1=t1)), timeout=timeout_s):
        t4 = clock()
        if reply.ok is None:
            continue
        try:
            echo = _echo_decoder.decode(reply.ok.payload.to_bytes())
        except msgspec.MsgspecError:
            continue
        if echo.t1 != t1 or echo.robot != peer:
            continue
        return sync.ClockSample(t1=t1, t2=echo.t2, t3=echo.t3, t4=t4)
    return None


class ClockTracker:
    """Probes every peer RAL every ``period_s`` (all of them, or the fixed ``peers``) and reports the offsets."""

    def __init__(self, session: zenoh.Session, robot: str, clock: Callable[[], float], *,
                 peers: list[str] | None = None, period_s: float = PROBE_PERIOD_S, publish: bool = True,
                 on_sample: Callable[[str, sync.ClockSample, sync.Estimate], None] | None = None) -> None:
        self.session = session
        self.robot = robot
        self.clock = clock
        self.period_s = period_s
        self.estimator = sync.OffsetEstimator()
        self.on_sample = on_sample
        self.lock = threading.Lock()
        self._peers: set[str] = set(peers or ())
        self._stop = threading.Event()
        self._entities: list[Any] = []
        if peers is None:
            self._entities.append(session.liveliness().declare_subscriber(
                keys.alive_pattern("*", "ral"), self._on_token, history=True))
        self._pub = (session.declare_publisher(s.clock_offsets_key(robot), encoding=wire.encoding_for(s.ClockReport))
                     if publish else None)
        self._thread = threading.Thread(target=self._run, name="ral.clock", daemon=True)
        self._thread.start()

    def _on_token(self, sample: zenoh.Sample) -> None:
        try:
            peer, _ = keys.parse_alive_key(str(sample.key_expr))
        except Exception:
            return
        if peer == self.robot:
            return
        with self.lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._peers.add(peer)
            else:
                self._peers.discard(peer)
                self.estimator.forget(peer)

    def estimate(self, peer: str) -> sync.Estimate | None:
        with self.lock:
            return self.estimator.estimate(peer, self.clock())

    def report(self) -> s.ClockReport:
        now = self.clock()
        with self.lock:
            peers = []
            for peer in self.estimator.peers():
                est = self.estimator.estimate(peer, now)
                if est is not None:
                    peers.append(s.PeerOffset(peer=peer, offset_s=est.offset_s, delay_s=est.delay_s,
                                              samples=est.samples, age_s=now - est.taken_at))
        return s.ClockReport(robot=self.robot, stamp=now, peers=peers)

    def _run(self) -> None:
        while not self._stop.is_set():
            with self.lock:
                peers = sorted(self._peers)
            for peer in peers:
                if self._stop.is_set():
                    return
                try:
                    sample = probe(self.session, peer, self.clock)
                except Exception:  # the session closing under us
                    return
                if sample is None:
                    continue
                with self.lock:
                    kept = self.estimator.add(peer, sample)
                    est = self.estimator.estimate(peer, sample.t4)
                if kept and est is not None and self.on_sample is not None:
                    self.on_sample(peer, sample, est)
            if self._pub is not None:
                try:
                    self._pub.put(_encoder.encode(self.report()))
                except Exception:
                    return
            self._stop.wait(self.period_s)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(PROBE_TIMEOUT_S + 0.5)  # a daemon: the RAL must stop within its grace
        for entity in self._entities:
            entity.undeclare()
        if self._pub is not None:
            self._pub.undeclare()


# ---------------------------------------------------------------- the RAL's sync service


class SyncNode:
    """A RAL's fleet-time part: clock service, offsets to every peer, synchronised start and formation keep.

    ``start_task(task)`` starts a task as a ground station's request would (the RAL's ``handle``: admission,
    no-fly zones, the manager); ``check_task(task)`` says why it would be refused now (None: it would not)."""

    def __init__(self, session: zenoh.Session, robot: str, clock: Callable[[], float],
                 start_task: Callable[[t.TaskParams], gri.TaskReply],
                 check_task: Callable[[t.TaskParams], str | None], *, period_s: float = PROBE_PERIOD_S) -> None:
        self.session = session
        self.robot = robot
        self.clock = clock
        self.start_task = start_task
        self.check_task = check_task
        self.service = ClockService(session, robot, clock)
        self.tracker = ClockTracker(session, robot, clock, period_s=period_s)
        self.started: list[s.SyncStarted] = []
        """What the synchronised starts did (the last 32)."""
        self._stop = threading.Event()
        self._formation: _Formation | None = None
        self._cancelled: set[str] = set()
        self._lock = threading.Lock()
        self._queryable = session.declare_queryable(s.sync_key(robot), self._on_request)

    def _on_request(self, query: zenoh.Query) -> None:
        """Answered on a thread of its own (checking a task may ask the manager: too slow for Zenoh's thread)."""
        wire.answer_in_thread(query, s.sync_key(self.robot), _request_decoder, self.handle,
                              lambda why: s.SyncReply(accepted=False, reason=f"invalid sync request: {why}"),
                              "ral.sync_request")

    def handle(self, request: s.SyncRequest) -> s.SyncReply:
        if isinstance(request, s.SyncStatus):
            with self._lock:
                starts = [x for x in self.started if x.group == request.group]
            return s.SyncReply(accepted=True, starts=starts)
        if isinstance(request, s.SyncCancel):
            with self._lock:
                if any(x.group == request.group for x in self.started):
                    return s.SyncReply(accepted=False, reason=f"{request.group} already started")
                self._cancelled.add(request.group)
            return s.SyncReply(accepted=True)
        if isinstance(request, s.StopFormation):
            self._stop_formation()
            return s.SyncReply(accepted=True)
        if isinstance(request, s.FormationKeep):
            if request.leader == self.robot:
                return s.SyncReply(accepted=False, reason="a robot cannot keep formation on itself")
            self._stop_formation()
            with self._lock:
                self._formation = _Formation(self, request)
            return s.SyncReply(accepted=True)
        why = self.check_task(request.task)
        if why is not None:
            return s.SyncReply(accepted=False, reason=why)
        plan = sync.plan_sync_start(robot=self.robot, reference=request.reference, start_at=request.start_at,
                                    own_now=self.clock(), estimate=self.tracker.estimate(request.reference))
        if isinstance(plan, sync.StartRefused):
            return s.SyncReply(accepted=False, reason=plan.reason)
        threading.Thread(target=self._start_at, args=(request, plan.local_start), name="ral.sync_start",
                         daemon=True).start()
        return s.SyncReply(accepted=True, local_start=plan.local_start)

    def _start_at(self, request: s.SyncStart, local_start: float) -> None:
        while not self._stop.is_set():
            left = local_start - self.clock()
            if left <= 0:
                break
            if left > 0.02:
                self._stop.wait(min(left - 0.01, 0.2))
            else:
                time.sleep(left / 2 if left > 0.0005 else 0)
        if self._stop.is_set():
            return
        with self._lock:
            cancelled = request.group in self._cancelled
            at = self.clock()
            if cancelled:
                self.started.append(s.SyncStarted(group=request.group, planned=local_start, started=at,
                                                  accepted=False, reason="cancelled: another robot refused"))
                return
            self.started.append(s.SyncStarted(group=request.group, planned=local_start, started=at, accepted=True,
                                              reason="starting"))
        reply = self.start_task(request.task)
        log.info("sync start %s at %.6f (planned %.6f): %s", request.group, at, local_start, reply)
        with self._lock:
            self.started = [x for x in self.started if x.group != request.group][-31:]
            self.started.append(s.SyncStarted(group=request.group, planned=local_start, started=at,
                                              accepted=reply.accepted, reason=reply.reason, task_id=reply.task_id))

    def _stop_formation(self) -> None:
        with self._lock:
            formation, self._formation = self._formation, None
        if formation is not None:
            formation.close()

    def close(self) -> None:
        self._stop.set()
        self._stop_formation()
        self._queryable.undeclare()
        self.tracker.close()
        self.service.close()


class _Formation:
    """Follows a leader's GRI state: a goto to leader + separation each time the goal moved enough."""

    def __init__(self, node: SyncNode, request: s.FormationKeep) -> None:
        self.node = node
        self.request = request
        self._goal: tuple[float, float, float] | None = None
        self._sent: tuple[float, float, float] | None = None
        self._sent_at: float | None = None
        self._wake = threading.Condition()
        self._closed = False
        self.sent: list[tuple[float, tuple[float, float, float], gri.TaskReply]] = []
        self._sub = node.session.declare_subscriber(gri.state_key(request.leader), self._on_state)
        self._thread = threading.Thread(target=self._run, name="ral.formation", daemon=True)
        self._thread.start()

    def _on_state(self, sample: zenoh.Sample) -> None:
        try:
            state = gri.decode_state(sample.payload.to_bytes())
        except msgspec.MsgspecError:
            return
        if state.position is None:
            return
        r = self.request
        with self._wake:
            self._goal = sync.formation_goal(state.position, r.north_m, r.east_m, r.up_m)
            self._wake.notify_all()

    def _run(self) -> None:
        while True:
            with self._wake:
                self._wake.wait(0.5)
                if self._closed:
                    return
                goal = self._goal
            now = self.node.clock()
            if goal is None or not sync.formation_resend(self._sent, goal, self._sent_at, now):
                continue
            lat, lon, alt = goal
            task = t.Goto(waypoints=[t.Waypoint(lat=lat, lon=lon, alt=alt)], speed=self.request.speed)
            reply = self.node.start_task(task)
            self._sent, self._sent_at = goal, now
            self.sent.append((now, goal, reply))
            if not reply.accepted:
                log.warning("formation goto refused: %s", reply.reason)

    def close(self) -> None:
        with self._wake:
            self._closed = True
            self._wake.notify_all()
        self._thread.join(2.0)
        self._sub.undeclare()
