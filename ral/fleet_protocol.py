"""The fleet allocation protocol as a pure state machine: what one RAL knows, bids and decides (no bus, no clock).

Rounds, per fleet task:

1. A RAL that learns a task (from the ground station's put, or from any peer's :class:`FleetState`) bids in
   round 0: its own state (position, speed, battery, time left on its current task, the target kinds it can do),
   frozen for the round. A robot whose kind cannot do any target publishes an abstention (``state`` None): it
   does not bid, but the others know it answered.
2. Once it holds a round's word from every live RAL (liveliness), or ``bid_window_s`` after the round began, it
   runs :func:`decide`, the deterministic auction of ``ral/allocation.py``, on those bids. Same bids → same
   result on every robot; the decision's ``digest`` lets anyone check it.
3. A new round (``round + 1``) starts when a robot that holds targets of the task drops out (liveliness lost),
   when a robot that abstained for a passing reason (no position yet, its task list not fetched yet) can bid,
   when a word arrives from a robot the decision did not hear (a late or healed robot), or when a peer published a
   different digest for the same round. Any RAL that sees a higher round joins it. In every round a robot's bid
   carries the targets it still has to visit (``remaining``, kept by it) and every target it knows visited
   (``done``, never auctioned again): a re-allocation auctions only the dropped robot's unvisited targets.
4. Each RAL flies its own share, as an ordinary task of its own robot (:class:`Execute`), and marks a target
   visited when its telemetry comes within ``reach_m`` of it.

Nothing here reads a clock: ``now`` is an argument (seconds since the epoch, the fleet's common time base).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import msgspec

from bbcs.contracts.fleet import BidState, FleetBid, FleetDecision, FleetState, FleetTarget, FleetTask
from bbcs.geodesy import distance_m, local_en
from ral.allocation import Bid, Target, allocate


@dataclass(frozen=True)
class FleetConfig:
    bid_window_s: float = 2.0
    """Longest wait for the word of every live RAL before deciding with the bids held."""
    period_s: float = 1.0
    """The fleet state is republished at least this often (late joiners, healed partitions, lost samples)."""
    reach_m: float = 10.0
    """A target counts as visited when the robot's horizontal position comes this close to it."""
    reach_alt_m: float = 5.0
    retry_s: float = 5.0
    """A share not being flown this long after it was sent (refused, or its task failed) is sent again."""


@dataclass(frozen=True)
class OwnState:
    """What the RAL knows of its own robot at a tick."""

    lat: float | None
    lon: float | None
    alt: float | None
    speed: float
    can_do: frozenset[str]
    battery: float | None = None
    busy_s: float = 0.0
    flying_share: bool = True
    """A movement task this protocol started is running (False: refused, failed or ended: send it again)."""
    available: bool = True
    """False while the robot's own failsafe is in force: it withdraws from every task it holds (they are
    allocated again without it) and flies none of them, even once its link is back."""


@dataclass(frozen=True)
class Execute:
    """Fly these targets in this order now (an ordinary movement task of this robot)."""

    task: FleetTask
    round: int
    targets: tuple[FleetTarget, ...]


@dataclass
class _Run:
    task: FleetTask
    round: int = 0
    started: float = 0.0
    bids: dict[str, FleetBid] = field(default_factory=dict)
    decision: FleetDecision | None = None
    heard: frozenset[str] = frozenset()
    """The robots whose word the decision used."""
    done: set[str] = field(default_factory=set)
    executing: tuple[str, ...] = ()
    sent: float = 0.0
    complete: bool = False
    withdrawn: bool = False


def horizontal_m(lat: float, lon: float, lat2: float, lon2: float) -> float:
    return distance_m(lat, lon, lat2, lon2)


def abstention(task: FleetTask, own: OwnState, withdrawn: bool) -> str:
    """Why this robot does not bid on ``task`` ("" when it bids): said in its bid, so that a ground station (and
    anyone reading the fleet states) sees why a target was left unassigned."""
    kinds = {t.kind for t in task.targets}
    if withdrawn or not own.available:
        return "its own failsafe is in force"
    if not kinds & own.can_do:
        can = ", ".join(sorted(own.can_do)) or "nothing"
        return f"it can do {can}, not {', '.join(sorted(kinds))}"
    if own.lat is None or own.lon is None:
        return "no position yet"
    if not own.speed > 0:
        return f"speed {own.speed:g} m/s"
    return ""


def decide(task: FleetTask, bids: Iterable[FleetBid], round_: int) -> FleetDecision:
    """The auction every RAL runs on one round's bids: deterministic in the set of bids (not their order)."""
    blist = sorted(bids, key=lambda b: b.robot)
    done = set().union(*(b.done for b in blist)) if blist else set()
    origin = min(task.targets, key=lambda t: t.id)
    targets = [Target(id=t.id, x=xy[0], y=xy[1], kind=t.kind, deadline=t.deadline)
               for t in task.targets if t.id not in done
               for xy in [local_en(origin.lat, origin.lon, t.lat, t.lon)]]
    bidding = [b for b in blist if b.state is not None]
    abids = []
    for b in bidding:
        s = b.state
        assert s is not None
        x, y = local_en(origin.lat, origin.lon, s.lat, s.lon)
        abids.append(Bid(robot=b.robot, x=x, y=y, speed=s.speed, battery=s.battery, busy_s=s.busy_s,
                         can_do=frozenset(s.can_do)))
    keep = {b.robot: [t for t in b.remaining if t not in done] for b in bidding}
    now = max((b.stamp for b in blist), default=0.0)
    alloc = allocate(targets, abids, now, max_per_robot=1 if task.one_per_robot else None, keep=keep,
                     balance=task.balance)
    routes = {r: list(route) for r, route in sorted(alloc.routes.items())}
    bidders = [b.robot for b in bidding]
    body = msgspec.msgpack.encode([task.id, round_, bidders, routes, list(alloc.unassigned)])
    return FleetDecision(task=task.id, round=round_, bidders=bidders, routes=routes,
                         unassigned=list(alloc.unassigned), cost=alloc.cost,
                         digest=hashlib.sha256(body).hexdigest()[:16], decided=now)


class FleetNode:
    """One RAL's side of the protocol. Feed it what the bus brings (``post``, ``on_state``, ``on_alive``,
    ``on_lost``) and call ``tick`` with the robot's own state; it returns what to fly, and ``state()`` what to
    publish when ``publish_due``."""

    def __init__(self, robot: str, kind: str, cfg: FleetConfig | None = None) -> None:
        self.robot = robot
        self.kind = kind
        self.cfg = cfg or FleetConfig()
        self.alive: set[str] = {robot}
        self.runs: dict[str, _Run] = {}
        self._dirty = True
        self._published = -math.inf
        self.decided_at: dict[tuple[str, int], float] = {}
        """(task, round) → when this node decided it (its clock): what re-allocation time is measured from."""

    # ------------------------------------------------------------------ inputs

    def post(self, task: FleetTask, now: float) -> None:
        """A task from a ground station or a peer; a task already known is not started again."""
        if task.id not in self.runs:
            self.runs[task.id] = _Run(task=task, started=now)
            self._dirty = True

    def on_alive(self, robot: str) -> None:
        self.alive.add(robot)

    def on_lost(self, robot: str, now: float) -> None:
        """A peer's RAL is gone: every unfinished task it bid on in the current round is allocated again."""
        if robot == self.robot:
            return
        self.alive.discard(robot)
        for run in self.runs.values():
            if not run.complete and robot in run.bids:
                self._new_round(run, run.round + 1, now)

    def on_state(self, st: FleetState, now: float) -> None:
        if st.robot == self.robot:
            return
        for task in st.tasks:
            self.post(task, now)
        for item in st.done:  # targets the peer knows visited (not used by decisions: those read the bids)
            task_id, _, target = item.partition("/")
            run = self.runs.get(task_id)
            if run is not None and target not in run.done:
                run.done.add(target)
                self._dirty = True
        for bid in st.bids:
            run = self.runs.get(bid.task)
            if run is None or run.complete:
                continue
            before = len(run.done)
            run.done.update(bid.done)
            if len(run.done) != before:
                self._dirty = True
            if {t.id for t in run.task.targets} <= run.done:
                continue  # finished: the next tick closes it
            if bid.round > run.round:
                self._new_round(run, bid.round, now)
            if bid.round == run.round and run.bids.get(bid.robot) != bid:
                run.bids[bid.robot] = bid
                if run.decision is not None and bid.robot not in run.heard:
                    self._new_round(run, run.round + 1, now)  # a word the decision did not hear
        for dec in st.decisions:
            run = self.runs.get(dec.task)
            if (run is not None and not run.complete and run.decision is not None and dec.round == run.round
                    and dec.digest != run.decision.digest):
                self._new_round(run, run.round + 1, now)

    def _new_round(self, run: _Run, round_: int, now: float) -> None:
        run.round, run.started = round_, now
        run.bids = {b.robot: b for b in run.bids.values() if b.round == round_}
        run.decision, run.heard = None, frozenset()
        self._dirty = True

    # ------------------------------------------------------------------ tick

    def tick(self, own: OwnState, now: float) -> list[Execute]:
        out: list[Execute] = []
        for run in self.runs.values():
            if run.complete:
                continue
            if not own.available and not run.withdrawn:
                run.withdrawn = True
                mine = run.bids.get(self.robot)
                if mine is not None and mine.state is not None:
                    self._new_round(run, run.round + 1, now)  # its word changes: everyone decides again
            mine = run.bids.get(self.robot)
            if mine is not None and mine.state is None and not abstention(run.task, own, run.withdrawn):
                self._new_round(run, run.round + 1, now)  # it can bid now (a position, its tasks): decide again
            if self.robot not in run.bids:
                run.bids[self.robot] = self._bid(run, own, now)
                self._dirty = True
            if run.decision is None and (self.alive <= set(run.bids) or now - run.started >= self.cfg.bid_window_s):
                run.decision = msgspec.structs.replace(decide(run.task, run.bids.values(), run.round), decided=now)
                run.heard = frozenset(run.bids)
                self.decided_at[(run.task.id, run.round)] = now
                self._dirty = True
            self._progress(run, own)
            if {t.id for t in run.task.targets} <= run.done:
                run.complete = True
                self._dirty = True
                continue
            mine = () if run.withdrawn else self._route(run)
            changed = mine != tuple(t for t in run.executing if t not in run.done)
            stalled = not own.flying_share and now - run.sent >= self.cfg.retry_s
            if mine and (changed or stalled):
                by_id = {t.id: t for t in run.task.targets}
                out.append(Execute(task=run.task, round=run.round, targets=tuple(by_id[t] for t in mine)))
                run.executing, run.sent = mine, now
        return out

    def _route(self, run: _Run) -> tuple[str, ...]:
        """This robot's unvisited targets under the current decision (or the last one it flew while deciding)."""
        if run.decision is None:
            return tuple(t for t in run.executing if t not in run.done)
        return tuple(t for t in run.decision.routes.get(self.robot, []) if t not in run.done)

    def _bid(self, run: _Run, own: OwnState, now: float) -> FleetBid:
        why = abstention(run.task, own, run.withdrawn)
        state = None
        if not why:
            assert own.lat is not None and own.lon is not None
            state = BidState(lat=own.lat, lon=own.lon, speed=own.speed, battery=own.battery, busy_s=own.busy_s,
                             can_do=sorted(own.can_do & {t.kind for t in run.task.targets}))
        return FleetBid(task=run.task.id, round=run.round, robot=self.robot, stamp=now, state=state, abstained=why,
                        remaining=list(self._route(run)) if state is not None else [],
                        done=sorted(run.done))

    def _progress(self, run: _Run, own: OwnState) -> None:
        if own.lat is None or own.lon is None or own.alt is None:
            return
        route = self._route(run)
        if not route:
            return
        nxt = next(t for t in run.task.targets if t.id == route[0])
        if (horizontal_m(own.lat, own.lon, nxt.lat, nxt.lon) <= self.cfg.reach_m
                and abs(own.alt - nxt.alt) <= self.cfg.reach_alt_m):
            run.done.add(nxt.id)
            self._dirty = True

    # ------------------------------------------------------------------ output

    def publish_due(self, now: float) -> bool:
        return self._dirty or now - self._published >= self.cfg.period_s

    def state(self, now: float) -> FleetState:
        self._dirty = False
        self._published = now
        runs = sorted(self.runs.values(), key=lambda r: r.task.id)
        return FleetState(
            robot=self.robot, kind=self.kind, stamp=now,
            tasks=[r.task for r in runs],
            bids=[r.bids[self.robot] for r in runs if self.robot in r.bids and not r.complete]
            + [_final_bid(r, self.robot, now) for r in runs if r.complete],
            decisions=[r.decision for r in runs if r.decision is not None],
            done=sorted(f"{r.task.id}/{t}" for r in runs for t in r.done),
        )

    def decision(self, task: str) -> FleetDecision | None:
        run = self.runs.get(task)
        return run.decision if run else None

    def visited(self, task: str) -> set[str]:
        run = self.runs.get(task)
        return set(run.done) if run else set()


def _final_bid(run: _Run, robot: str, now: float) -> FleetBid:
    """A finished task: the word that tells peers every target is visited."""
    return FleetBid(task=run.task.id, round=run.round, robot=robot, stamp=now, done=sorted(run.done))
