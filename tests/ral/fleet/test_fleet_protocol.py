"""The fleet protocol (ral/fleet_protocol.py) with an injected clock and a simulated network of FleetNodes: every
robot reaches the same allocation, a kind that cannot do a task does not bid, a dropped robot's unvisited targets
go to the others, late joiners and healed partitions converge to one result again."""

from __future__ import annotations

import dataclasses
import math
import random

from bbcs.contracts.fleet import FleetTarget, FleetTask
from ral.fleet_protocol import Execute, FleetConfig, FleetNode, OwnState, decide

LAT0, LON0, ALT = 37.4117, -6.0025, 30.0
M = 1 / 111_320  # degrees of latitude per metre


def target(i: int, north_m: float, east_m: float, kind: str = "visit") -> FleetTarget:
    return FleetTarget(id=f"t{i:02d}", lat=LAT0 + north_m * M, lon=LON0 + east_m * M / math.cos(math.radians(LAT0)),
                       alt=ALT, kind=kind)


def own(north_m: float, east_m: float, can_do: frozenset[str] = frozenset({"visit"})) -> OwnState:
    t = target(0, north_m, east_m)
    return OwnState(lat=t.lat, lon=t.lon, alt=ALT, speed=5.0, can_do=can_do)


class Net:
    """Nodes that see each other's published state after every tick (in a shuffled order), unless cut off."""

    def __init__(self, positions: dict[str, tuple[float, float]], kinds: dict[str, frozenset[str]] | None = None,
                 seed: int = 0) -> None:
        self.nodes = {r: FleetNode(r, "uav", FleetConfig(bid_window_s=2.0)) for r in positions}
        for n in self.nodes.values():
            for r in positions:
                n.on_alive(r)
        self.pos = dict(positions)
        self.kinds = kinds or {}
        self.rng = random.Random(seed)
        self.cut: set[str] = set()
        self.now = 1000.0
        self.flown: dict[str, list[Execute]] = {r: [] for r in positions}
        self.failsafe: set[str] = set()
        self.blind: set[str] = set()
        """Robots without a position (no telemetry yet)."""

    def step(self, dt: float = 0.1) -> None:
        self.now += dt
        states = []
        for r, n in self.nodes.items():
            own_state = own(*self.pos[r], can_do=self.kinds.get(r, frozenset({"visit"})))
            if r in self.failsafe:
                own_state = dataclasses.replace(own_state, available=False)
            if r in self.blind:
                own_state = dataclasses.replace(own_state, lat=None, lon=None, alt=None)
            self.flown[r] += n.tick(own_state, self.now)
            states.append(n.state(self.now))
        for st in states:
            receivers = list(self.nodes.items())
            self.rng.shuffle(receivers)
            for r, n in receivers:
                if r != st.robot and not ({r, st.robot} & self.cut):
                    n.on_state(st, self.now)

    def run(self, seconds: float) -> None:
        for _ in range(int(seconds / 0.1)):
            self.step()

    def digests(self, task: str) -> dict[str, str | None]:
        return {r: (d.digest if (d := n.decision(task)) else None) for r, n in self.nodes.items()}


TASK = FleetTask(id="survey1", targets=[target(i, 100.0 * (i % 3), 120.0 * (i // 3)) for i in range(9)])


def test_every_robot_reaches_the_same_allocation_and_flies_only_its_share() -> None:
    net = Net({"a": (0, 0), "b": (0, 300), "c": (250, 150)})
    net.nodes["b"].post(TASK, net.now)  # the ground station's put reached one robot only: the others learn it
    net.run(1.0)
    digests = net.digests("survey1")
    assert len(set(digests.values())) == 1 and None not in digests.values(), digests
    dec = net.nodes["a"].decision("survey1")
    assert dec is not None and dec.round == 0 and dec.bidders == ["a", "b", "c"]
    assert sorted(t for r in dec.routes.values() for t in r) == [t.id for t in TASK.targets]
    again = decide(TASK, net.nodes["c"].runs["survey1"].bids.values(), 0)
    assert (again.digest, again.routes) == (dec.digest, dec.routes)
    assert "t00" in net.nodes["b"].visited("survey1"), "a sits on t00: visited at once, and every robot knows"
    for r, flown in net.flown.items():
        share = [t for t in dec.routes[r] if t != "t00"]
        assert len(flown) == (1 if share else 0) and [t.id for t in flown[0].targets] == share, (r, flown)


def test_the_result_does_not_depend_on_message_order() -> None:
    results = set()
    for seed in range(6):
        net = Net({"a": (0, 0), "b": (0, 300), "c": (250, 150), "d": (-50, 80)}, seed=seed)
        for n in net.nodes.values():
            n.post(TASK, net.now)
        net.run(1.0)
        results.add(tuple(net.digests("survey1").values()))
    assert len(results) == 1 and len(set(next(iter(results)))) == 1


def test_a_kind_that_cannot_do_the_task_does_not_bid() -> None:
    task = FleetTask(id="mixed", targets=[target(1, 0, 50, "visit"), target(2, 50, 0, "inspect")])
    net = Net({"uav": (0, 0), "quad": (10, 10), "rover": (0, 5)},
              kinds={"uav": frozenset({"visit", "inspect"}), "quad": frozenset({"inspect"}),
                     "rover": frozenset({"drive"})})
    net.nodes["uav"].post(task, net.now)
    net.run(1.0)
    dec = net.nodes["rover"].decision("mixed")
    assert dec is not None and dec.bidders == ["quad", "uav"], dec
    assert "t01" not in dec.routes["quad"] and "rover" not in dec.routes
    rover_bid = net.nodes["rover"].runs["mixed"].bids["rover"]
    assert rover_bid.state is None, "the rover abstains: its word, no bid"
    assert net.nodes["quad"].runs["mixed"].bids["quad"].state.can_do == ["inspect"]
    assert net.flown["rover"] == []


def test_an_abstention_says_why_and_a_robot_that_can_bid_later_is_decided_with() -> None:
    """Robots without a position when the task comes abstain, saying so, and the targets are left unassigned; once
    they have one, a new round takes them in and every robot agrees on it (a passing reason does not leave the
    task unflown for good), while a kind that cannot do it stays out."""
    net = Net({"a": (0, 0), "b": (0, 300), "c": (250, 150)}, kinds={"c": frozenset({"drive"})})
    net.blind = {"a", "b"}
    net.nodes["a"].post(TASK, net.now)
    net.run(1.0)
    first = net.nodes["a"].decision("survey1")
    assert first is not None and first.bidders == [] and len(first.unassigned) == len(TASK.targets), first
    bids = {r: n.runs["survey1"].bids[r] for r, n in net.nodes.items()}
    assert bids["a"].state is None and bids["a"].abstained == "no position yet"
    assert bids["c"].state is None and bids["c"].abstained == "it can do drive, not visit"
    assert net.flown == {"a": [], "b": [], "c": []}
    net.blind = set()
    net.run(1.0)
    after = net.nodes["c"].decision("survey1")
    assert after is not None and after.round >= 1 and after.bidders == ["a", "b"] and not after.unassigned, after
    assert len(set(net.digests("survey1").values())) == 1 and after.routes["a"] and after.routes["b"], after
    assert net.flown["a"] and net.flown["b"] and not net.flown["c"]
    net.run(1.0)
    assert net.nodes["a"].decision("survey1").round == after.round, "c's abstention is for good: no further round"


def test_a_robot_that_drops_out_has_its_unvisited_targets_reallocated() -> None:
    net = Net({"a": (0, 0), "b": (0, 300), "c": (250, 150)})
    net.nodes["a"].post(TASK, net.now)
    net.run(1.0)
    first = net.nodes["a"].decision("survey1")
    assert first is not None
    lost = first.routes["c"]
    assert len(lost) >= 2, first.routes
    # c visits its first target, everyone hears it, then c dies
    tgt = next(t for t in TASK.targets if t.id == lost[0])
    net.pos["c"] = ((tgt.lat - LAT0) / M, (tgt.lon - LON0) / M * math.cos(math.radians(LAT0)))
    net.run(0.5)
    seen = net.nodes["a"].visited("survey1")
    assert lost[0] in seen and lost[1] not in seen
    del net.nodes["c"]
    killed = net.now
    for n in net.nodes.values():
        n.on_lost("c", net.now)
    net.run(0.5)
    after = net.nodes["a"].decision("survey1")
    assert after is not None and after.round == 1 and after.bidders == ["a", "b"]
    assert net.digests("survey1")["b"] == after.digest
    assert net.nodes["a"].decided_at[("survey1", 1)] - killed <= 0.25, "after one exchange, not a timeout"
    for r in ("a", "b"):  # survivors keep their routes in order, the lost targets are added, the visited one not
        assert [t for t in after.routes[r] if t in first.routes[r]] == [t for t in first.routes[r] if t not in seen]
    assert sorted(t for r in after.routes.values() for t in r) == sorted(t.id for t in TASK.targets
                                                                         if t.id not in seen)
    assert any(set(lost[1:]) & {t.id for t in x.targets} for r in ("a", "b") for x in net.flown[r][1:])


def test_a_silent_robot_is_decided_without_after_the_bid_window() -> None:
    net = Net({"a": (0, 0), "b": (0, 300)})
    net.nodes["a"].on_alive("ghost")  # alive token seen, but it never answers
    net.nodes["b"].on_alive("ghost")
    net.nodes["a"].post(TASK, net.now)
    net.run(1.0)
    assert net.nodes["a"].decision("survey1") is None
    net.run(1.5)
    assert len(set(net.digests("survey1").values())) == 1 and net.nodes["a"].decision("survey1").bidders == ["a", "b"]


def test_a_partition_heals_into_one_allocation() -> None:
    net = Net({"a": (0, 0), "b": (0, 300), "c": (250, 150)})
    net.cut = {"c"}
    net.nodes["a"].post(TASK, net.now)
    net.nodes["c"].post(TASK, net.now)
    net.run(3.0)  # two sides, each decides on its own (after the bid window): different results
    assert net.digests("survey1")["a"] == net.digests("survey1")["b"] != net.digests("survey1")["c"]
    net.cut = set()
    net.run(3.0)
    digests = net.digests("survey1")
    assert len(set(digests.values())) == 1, digests
    dec = net.nodes["a"].decision("survey1")
    assert dec.bidders == ["a", "b", "c"]
    owners = [t for r in dec.routes.values() for t in r]
    assert sorted(owners) == sorted(set(owners)), "a target held by both sides goes to one robot"


def test_a_robot_in_failsafe_withdraws_and_its_targets_go_to_the_others() -> None:
    net = Net({"a": (0, 0), "b": (0, 300), "c": (250, 150)})
    net.nodes["a"].post(TASK, net.now)
    net.run(1.0)
    first = net.nodes["a"].decision("survey1")
    assert first is not None and first.routes["c"]
    flown_before = len(net.flown["c"])
    net.failsafe = {"c"}  # c's own link-loss failsafe fired: it is alive but must not fly fleet work
    net.run(1.0)
    after = net.nodes["a"].decision("survey1")
    assert after.round >= 1 and after.bidders == ["a", "b"], after
    assert len(set(net.digests("survey1").values())) == 1
    assert set(first.routes["c"]) <= {t for r in ("a", "b") for t in after.routes[r]}
    net.failsafe = set()  # link back: the failsafe stays in force for the tasks it withdrew from
    net.run(1.0)
    assert len(net.flown["c"]) == flown_before and net.nodes["a"].decision("survey1").bidders == ["a", "b"]


def test_a_share_not_being_flown_is_sent_again_after_retry_s() -> None:
    node = FleetNode("a", "uav", FleetConfig(retry_s=5.0))
    node.post(TASK, 0.0)
    me = dataclasses.replace(own(-500, -500), flying_share=False)
    sent = [t for t in (0.0, 1.0, 4.0, 5.5, 6.0, 11.0) for _ in node.tick(me, t)]
    assert sent == [0.0, 5.5, 11.0]
