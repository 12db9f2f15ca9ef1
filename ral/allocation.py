"""Fleet task allocation: a sequential auction with best-position insertion and pairwise-swap repair.

Pure and deterministic, so every RAL that holds the same bids computes the same allocation without a central
allocator: no randomness, no dict-order dependence, ties broken by (cost, robot name, target id), and time comes
in as an argument (``now``), never from a clock read here. A :class:`Bid` is what one robot states about itself
(position, speed, battery, time left on its current task, kind and what it can do); the cost of a target for a
robot is computed from that bid alone. A robot that cannot do a target's kind does not bid on it; a target nobody
can reach before its deadline stays unassigned and is reported as such.

Exchanging the bids over the bus between RALs is not built yet (docs/fleet.md): this module is the decision.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

BATTERY_WEIGHT = 1.0
"""A robot with an empty battery bids (1 + BATTERY_WEIGHT) times its travel time; a full one, its travel time."""


@dataclass(frozen=True)
class Target:
    """A place to visit: local east/north metres (a shared local frame), the task kind it needs, a deadline."""

    id: str
    x: float
    y: float
    kind: str = "visit"
    deadline: float | None = None
    """Absolute time (same clock as ``now``) by which a robot must arrive; None: no deadline."""


@dataclass(frozen=True)
class Bid:
    """One robot's own state, which is all its bids are computed from."""

    robot: str
    x: float
    y: float
    speed: float = 5.0
    """Metres per second (must be > 0)."""
    battery: float | None = None
    """State of charge 0..1, None when the robot does not know."""
    busy_s: float = 0.0
    """Seconds left on its current task before it can start fleet work."""
    can_do: frozenset[str] = frozenset({"visit"})


@dataclass(frozen=True)
class Allocation:
    """Who visits what, in order; the total cost (sum of the robots' weighted route times); what nobody can do."""

    routes: Mapping[str, tuple[str, ...]]
    cost: float
    unassigned: tuple[str, ...] = ()
    costs: Mapping[str, float] = field(default_factory=dict)

    def owner(self, target: str) -> str | None:
        return next((r for r, route in self.routes.items() if target in route), None)


def _factor(bid: Bid) -> float:
    if bid.battery is None:
        return 1.0
    return 1.0 + BATTERY_WEIGHT * (1.0 - min(1.0, max(0.0, bid.battery)))


def _check(bids: Sequence[Bid], targets: Sequence[Target]) -> None:
    names = [b.robot for b in bids]
    if len(set(names)) != len(names):
        raise ValueError(f"two bids under one robot name: {sorted(names)}")
    ids = [t.id for t in targets]
    if len(set(ids)) != len(ids):
        raise ValueError(f"two targets with one id: {sorted(ids)}")
    for b in bids:
        if not (b.speed > 0 and math.isfinite(b.speed)):
            raise ValueError(f"robot {b.robot}: speed must be a positive number, not {b.speed}")
        if not (math.isfinite(b.x) and math.isfinite(b.y) and b.busy_s >= 0):
            raise ValueError(f"robot {b.robot}: position must be finite and busy_s >= 0")


def route_cost(bid: Bid, route: Sequence[Target]) -> float:
    """Weighted time for ``bid``'s robot to fly its route from where it is (its current task first)."""
    return _factor(bid) * (bid.busy_s + _length(bid, route) / bid.speed)


def _length(bid: Bid, route: Sequence[Target]) -> float:
    d, x, y = 0.0, bid.x, bid.y
    for t in route:
        d += math.hypot(t.x - x, t.y - y)
        x, y = t.x, t.y
    return d


def _arrivals_ok(bid: Bid, route: Sequence[Target], now: float) -> bool:
    tt, x, y = now + bid.busy_s, bid.x, bid.y
    for t in route:
        tt += math.hypot(t.x - x, t.y - y) / bid.speed
        x, y = t.x, t.y
        if t.deadline is not None and tt > t.deadline:
            return False
    return True


def _best_insertion(bid: Bid, route: list[Target], target: Target, now: float) -> tuple[float, int] | None:
    """Cheapest (marginal cost, position) to insert ``target`` in ``route``; None if no position meets deadlines."""
    if target.deadline is None and all(t.deadline is None for t in route):
        return _cheap_insertion(bid, route, target)
    base = route_cost(bid, route) if route else 0.0  # the first target also pays for finishing the current task
    best: tuple[float, int] | None = None
    for pos in range(len(route) + 1):
        trial = route[:pos] + [target] + route[pos:]
        if not _arrivals_ok(bid, trial, now):
            continue
        marginal = route_cost(bid, trial) - base
        if best is None or marginal < best[0] - 1e-12:
            best = (marginal, pos)
    return best


def _cheap_insertion(bid: Bid, route: list[Target], target: Target) -> tuple[float, int]:
    """No deadline in play: the marginal cost of each position is the detour it adds, in O(1) per position."""
    f = _factor(bid)
    best_delta, best_pos = math.inf, 0
    px, py = bid.x, bid.y
    for pos in range(len(route) + 1):
        into = math.hypot(target.x - px, target.y - py)
        if pos < len(route):
            nxt = route[pos]
            delta = into + math.hypot(nxt.x - target.x, nxt.y - target.y) - math.hypot(nxt.x - px, nxt.y - py)
        else:
            delta = into
        if delta < best_delta - 1e-12:
            best_delta, best_pos = delta, pos
        if pos < len(route):
            px, py = route[pos].x, route[pos].y
    return f * (best_delta / bid.speed + (0.0 if route else bid.busy_s)), best_pos


def allocate(targets: Iterable[Target], bids: Iterable[Bid], now: float = 0.0, *,
             max_per_robot: int | None = None, keep: Mapping[str, Sequence[str]] | None = None,
             balance: bool = False) -> Allocation:
    """Allocate ``targets`` among the robots that bid; the same inputs give the same result everywhere.

    ``keep``: routes already held (robot → target ids, e.g. after a re-allocation), auctioned first to their
    holders in order; only targets of robots still bidding are kept.
    ``balance``: each round goes to the lowest time at which a robot would finish its route with the target in
    it, not the lowest detour: the work is shared so that the last robot finishes sooner (an area to survey),
    where the least total flight would leave one robot doing everything near it.
    """
    tlist = sorted(targets, key=lambda t: t.id)
    blist = sorted(bids, key=lambda b: b.robot)
    _check(blist, tlist)
    by_id = {t.id: t for t in tlist}
    by_robot = {b.robot: b for b in blist}
    routes: dict[str, list[Target]] = {b.robot: [] for b in blist}
    open_ids = set(by_id)
    for robot, ids in sorted((keep or {}).items()):
        if robot in routes:
            for tid in ids:
                if tid in open_ids:
                    routes[robot].append(by_id[tid])
                    open_ids.discard(tid)
    while open_ids:
        held = {r: route_cost(by_robot[r], rt) if rt else 0.0 for r, rt in routes.items()} if balance else {}
        best: tuple[float, str, str, int] | None = None
        for tid in sorted(open_ids):
            t = by_id[tid]
            for b in blist:
                if t.kind not in b.can_do:
                    continue  # this kind of robot does not bid
                if max_per_robot is not None and len(routes[b.robot]) >= max_per_robot:
                    continue
                ins = _best_insertion(b, routes[b.robot], t, now)
                if ins is None:
                    continue
                value = ins[0] + (held[b.robot] if balance else 0.0)
                cand = (value, b.robot, tid, ins[1])
                if best is None or cand < best:
                    best = cand
        if best is None:
            break
        _, robot, tid, pos = best
        routes[robot].insert(pos, by_id[tid])
        open_ids.discard(tid)
    if max_per_robot == 1:
        _swap_repair(routes, by_robot, now)
    costs = {r: route_cost(by_robot[r], rt) if rt else 0.0 for r, rt in routes.items()}
    return Allocation(routes={r: tuple(t.id for t in rt) for r, rt in routes.items()},
                      cost=sum(costs.values()), unassigned=tuple(sorted(open_ids)), costs=costs)


def _swap_repair(routes: dict[str, list[Target]], bids: Mapping[str, Bid], now: float) -> None:
    """One-target routes: exchange targets between two robots (or move one to an idle robot) while that lowers the
    total; a fixed scan order keeps it deterministic."""
    names = sorted(routes)
    improved = True
    while improved:
        improved = False
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                ra, rb = routes[a], routes[b]
                if not ra and not rb:
                    continue
                ba, bb = bids[a], bids[b]
                if any(t.kind not in bb.can_do for t in ra) or any(t.kind not in ba.can_do for t in rb):
                    continue
                if not (_arrivals_ok(ba, rb, now) and _arrivals_ok(bb, ra, now)):
                    continue
                old = (route_cost(ba, ra) if ra else 0.0) + (route_cost(bb, rb) if rb else 0.0)
                new = (route_cost(ba, rb) if rb else 0.0) + (route_cost(bb, ra) if ra else 0.0)
                if new < old - 1e-9:
                    routes[a], routes[b] = rb, ra
                    improved = True


def reallocate(previous: Allocation, targets: Iterable[Target], bids: Iterable[Bid], now: float, *,
               done: Iterable[str] = (), max_per_robot: int | None = None, balance: bool = False) -> Allocation:
    """After a robot drops out (it no longer bids): survivors keep their remaining routes, the dropped robots'
    targets (minus those ``done``) are auctioned again among them."""
    finished = set(done)
    remaining = [t for t in targets if t.id not in finished]
    live = list(bids)
    alive = {b.robot for b in live}
    keep = {r: [t for t in route if t not in finished] for r, route in previous.routes.items() if r in alive}
    return allocate(remaining, live, now, max_per_robot=max_per_robot, keep=keep, balance=balance)


def cost_matrix(targets: Sequence[Target], bids: Sequence[Bid]) -> list[list[float]]:
    """Robot × target cost of a one-target route (inf where the robot cannot do the target): what the central
    optimum of the one-target-per-robot case is computed over."""
    return [[route_cost(b, [t]) if t.kind in b.can_do else math.inf for t in targets] for b in bids]
