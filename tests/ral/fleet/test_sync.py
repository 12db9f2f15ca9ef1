"""Fleet time, pure (ral/sync.py): the four-timestamp offset, the minimum-delay filter, the synchronised start's
local instant, the formation goal; then on real Zenoh: skewed robots' clocks recovered by the tracker."""

from __future__ import annotations

import math
import random

import pytest

from bbcs.contracts.geo import GeoPoint
from bbcs.geodesy import distance_m
from bbcs.testing import wait_until
from ral import sync
from ral.sync_bus import ClockService, ClockTracker


def exchange(true_offset: float, t1: float, out_s: float, back_s: float, proc_s: float = 0.0001) -> sync.ClockSample:
    """A probe sent at own-clock ``t1`` that takes ``out_s`` to the peer and ``back_s`` back."""
    t2 = t1 + out_s + true_offset
    t3 = t2 + proc_s
    t4 = t3 - true_offset + back_s
    return sync.ClockSample(t1=t1, t2=t2, t3=t3, t4=t4)


def test_symmetric_exchange_gives_the_exact_offset_and_the_delay() -> None:
    sample = exchange(2.5, t1=100.0, out_s=0.003, back_s=0.003)
    assert sample.offset == pytest.approx(2.5, abs=1e-9)
    assert sample.delay == pytest.approx(0.006, abs=1e-9)


def test_asymmetry_errs_by_half_the_difference_and_the_min_delay_sample_wins() -> None:
    est = sync.OffsetEstimator()
    rng = random.Random(3)
    t1 = 1000.0
    for _ in range(7):  # queued samples: long, asymmetric delays
        out, back = rng.uniform(0.01, 0.05), rng.uniform(0.0, 0.002)
        assert est.add("b", exchange(-1.25, t1, out, back))
        t1 += 0.5
    assert est.add("b", exchange(-1.25, t1, 0.0004, 0.0006))  # one quick exchange
    e = est.estimate("b", now=t1 + 0.1)
    assert e is not None and e.samples == 8
    assert e.delay_s == pytest.approx(0.001 + 0.0001 - 0.0001, abs=1e-6)
    assert e.offset_s == pytest.approx(-1.25 + (0.0004 - 0.0006) / 2, abs=1e-9)
    worst_single = exchange(-1.25, 0.0, 0.05, 0.0).offset
    assert abs(worst_single + 1.25) > 0.02  # a single queued sample would have been 25 ms off


def test_window_slides_old_samples_expire_and_impossible_samples_are_refused() -> None:
    est = sync.OffsetEstimator(window=3, max_age_s=10.0)
    for i in range(5):
        est.add("p", exchange(1.0 + i, float(i), 0.001, 0.001))
    e = est.estimate("p", now=4.5)
    assert e is not None and e.samples == 3 and e.offset_s == pytest.approx(4.0, abs=1e-6)  # ties: newest
    assert est.estimate("p", now=100.0) is None  # all stale
    assert not est.add("p", sync.ClockSample(t1=10.0, t2=0.0, t3=5.0, t4=9.0))  # negative delay
    assert not est.add("p", sync.ClockSample(t1=math.nan, t2=0.0, t3=0.0, t4=1.0))
    assert est.estimate("nobody", 0.0) is None
    with pytest.raises(ValueError):
        sync.OffsetEstimator(window=0)


def test_skewed_clock_is_off_by_its_offset_plus_drift() -> None:
    now = [1000.0]
    clock = sync.SkewedClock(offset_s=-0.7, drift_ppm=100.0, base=lambda: now[0])
    assert clock() == pytest.approx(999.3)
    now[0] = 2000.0
    assert clock() == pytest.approx(2000.0 - 0.7 + 0.1)
    assert clock.error_at(2000.0) == pytest.approx(-0.6)


def est(offset: float, delay: float = 0.002) -> sync.Estimate:
    return sync.Estimate(offset_s=offset, delay_s=delay, samples=8, taken_at=0.0)


def test_sync_start_converts_the_reference_instant_to_the_own_clock() -> None:
    # the reference's clock is 3 s ahead of ours: its 1005.0 is our 1002.0
    plan = sync.plan_sync_start(robot="b", reference="a", start_at=1005.0, own_now=1000.0, estimate=est(3.0))
    assert plan == sync.StartPlan(local_start=1002.0)
    own = sync.plan_sync_start(robot="a", reference="a", start_at=1005.0, own_now=1004.0, estimate=None)
    assert own == sync.StartPlan(local_start=1005.0)


@pytest.mark.parametrize(("kwargs", "why"), [
    ({"estimate": None}, "no clock offset to the reference robot 'a'"),
    ({"estimate": est(0.0, delay=0.2)}, "too uncertain"),
    ({"start_at": 990.0}, "in the past"),
    ({"start_at": 1000.1}, "only 0.100 s ahead"),
    ({"start_at": 1e9}, "more than"),
    ({"start_at": math.nan}, "not a number"),
])
def test_sync_start_refusals_say_why(kwargs: dict, why: str) -> None:
    args = {"robot": "b", "reference": "a", "start_at": 1005.0, "own_now": 1000.0, "estimate": est(0.0)} | kwargs
    plan = sync.plan_sync_start(**args)
    assert isinstance(plan, sync.StartRefused) and why in plan.reason, plan


def test_formation_goal_and_resend_rule() -> None:
    leader = GeoPoint(lat=37.4, lon=-6.0, alt=50.0)
    goal = sync.formation_goal(leader, north_m=0.0, east_m=20.0, up_m=5.0)
    assert distance_m(leader.lat, leader.lon, goal[0], goal[1]) == pytest.approx(20.0, abs=0.01)
    assert goal[2] == 55.0 and goal[0] == pytest.approx(leader.lat)
    follower = GeoPoint(lat=goal[0], lon=goal[1], alt=goal[2])
    assert sync.separation_error_m(follower, leader, 0.0, 20.0, 5.0) == pytest.approx(0.0, abs=1e-6)
    assert sync.separation_error_m(follower, leader, 0.0, 30.0, 5.0) == pytest.approx(10.0, abs=0.01)
    assert sync.formation_resend(None, goal, None, 0.0)
    moved = sync.formation_goal(GeoPoint(lat=37.4, lon=-6.0 + 1e-4, alt=50.0), 0.0, 20.0, 5.0)  # ~8.8 m east
    assert not sync.formation_resend(goal, moved, last_sent_at=10.0, now=10.5)  # too soon
    assert sync.formation_resend(goal, moved, last_sent_at=10.0, now=11.5)
    assert not sync.formation_resend(goal, goal, last_sent_at=10.0, now=20.0)  # the leader did not move


def test_trackers_on_real_zenoh_recover_injected_skews(router: int, clients) -> None:
    clocks = {"uav_a": sync.SkewedClock(offset_s=1.5), "uav_b": sync.SkewedClock(offset_s=-0.8),
              "uav_c": sync.SkewedClock(offset_s=0.0, drift_ppm=200.0)}
    sessions = {name: clients(router) for name in clocks}
    services = [ClockService(sessions[n], n, clocks[n]) for n in clocks]
    trackers = {n: ClockTracker(sessions[n], n, clocks[n], peers=[p for p in clocks if p != n], period_s=0.1)
                for n in clocks}
    try:
        def full() -> bool:
            return all(trackers[n].estimator.estimate(p, clocks[n]()) is not None
                       and trackers[n].estimator.estimate(p, clocks[n]()).samples >= 5
                       for n in clocks for p in clocks if p != n)

        wait_until(full, 30, "five clock samples of every peer at every robot")
        import time
        base = time.time()
        for n in clocks:
            report = trackers[n].report()
            assert report.robot == n and sorted(p.peer for p in report.peers) == sorted(set(clocks) - {n})
            for p in report.peers:
                truth = clocks[p.peer].error_at(base) - clocks[n].error_at(base)
                assert p.offset_s == pytest.approx(truth, abs=0.02), (n, p)
                assert p.offset_s == pytest.approx(truth, abs=p.delay_s / 2 + 0.002), (n, p)
    finally:
        for tr in trackers.values():
            tr.close()
        for sv in services:
            sv.close()


def test_sync_node_starts_at_the_agreed_instant_refuses_clearly_and_keeps_formation(router: int, clients) -> None:
    import time

    import msgspec

    from bbcs.contracts import gri
    from bbcs.contracts import sync as s
    from bbcs.contracts import tasks as t
    from ral.sync_bus import SyncNode

    clocks = {"uav_a": sync.SkewedClock(offset_s=0.7), "uav_b": sync.SkewedClock(offset_s=-0.4)}
    started: dict[str, list[tuple[float, t.TaskParams]]] = {n: [] for n in clocks}

    def starter(name: str):
        def start(task: t.TaskParams) -> gri.TaskReply:
            started[name].append((time.time(), task))
            return gri.TaskReply(accepted=True, task_id=len(started[name]))
        return start

    def check(task: t.TaskParams) -> str | None:
        return "this robot has no task 'land'" if isinstance(task, t.Land) else None

    from bbcs import keys

    sessions = {n: clients(router) for n in clocks}
    tokens = [sessions[n].liveliness().declare_token(keys.alive_key(n, "ral")) for n in clocks]  # as the RALs hold
    made = {n: SyncNode(sessions[n], n, clocks[n], starter(n), check, period_s=0.1) for n in clocks}
    try:
        gcs = clients(router)
        early = made["uav_b"].handle(s.SyncStart(group="g0", reference="uav_c", start_at=0.0, task=t.TakeOff()))
        assert not early.accepted and "no clock offset to the reference robot 'uav_c'" in early.reason
        wait_until(lambda: made["uav_b"].tracker.estimate("uav_a") is not None
                   and made["uav_b"].tracker.estimate("uav_a").samples >= 3, 20, "uav_b's offset to uav_a")
        start_at = clocks["uav_a"]() + 1.0
        request = s.SyncStart(group="g1", reference="uav_a", start_at=start_at, task=t.TakeOff())
        replies = {}
        for n in clocks:
            for reply in gcs.get(s.sync_key(n), payload=msgspec.msgpack.encode(request), timeout=10.0):
                replies[n] = msgspec.msgpack.decode(reply.ok.payload.to_bytes(), type=s.SyncReply)
        assert all(r.accepted for r in replies.values()), replies
        wait_until(lambda: all(started[n] for n in clocks), 20, "both started")
        host_instant = start_at - 0.7
        for n in clocks:
            at, task = started[n][0]
            assert task == t.TakeOff() and at >= host_instant - 0.005, (n, at - host_instant)
        wait_until(lambda: [x.task_id for x in made["uav_b"].handle(s.SyncStatus(group="g1")).starts] == [1], 10,
                   "uav_b's start recorded with its task")
        status = made["uav_b"].handle(s.SyncStatus(group="g1")).starts
        assert status[0].accepted
        assert status[0].started >= status[0].planned
        refused = made["uav_a"].handle(s.SyncStart(group="g2", reference="uav_a", start_at=clocks["uav_a"]() + 5,
                                                   task=t.Land()))
        assert not refused.accepted and refused.reason == "this robot has no task 'land'"
        past = made["uav_b"].handle(s.SyncStart(group="g3", reference="uav_a", start_at=start_at - 10,
                                                task=t.TakeOff()))
        assert not past.accepted and "in the past" in past.reason

        # formation: uav_b follows uav_a's GRI state 20 m east
        assert not made["uav_a"].handle(s.FormationKeep(leader="uav_a")).accepted
        assert made["uav_b"].handle(s.FormationKeep(leader="uav_a", east_m=20.0)).accepted
        lead = GeoPoint(lat=37.41, lon=-6.0, alt=40.0)
        from bbcs.contracts.robot import RobotTelemetry
        state = gri.GriState(robot="uav_a", stamp=0.0, telemetry=RobotTelemetry(stamp=0.0, position=lead))
        before = len(started["uav_b"])

        def goto_sent() -> bool:
            gcs.put(gri.state_key("uav_a"), gri.encode(state))
            return any(isinstance(task, t.Goto) for _, task in started["uav_b"][before:])

        wait_until(goto_sent, 20, "the follower's goto")
        goto = next(task for _, task in started["uav_b"][before:] if isinstance(task, t.Goto))
        point = goto.waypoints[0]
        follower = GeoPoint(lat=point.lat, lon=point.lon, alt=point.alt)
        assert sync.separation_error_m(follower, lead, 0.0, 20.0, 0.0) < 0.01
        assert made["uav_b"].handle(s.StopFormation()).accepted
    finally:
        for node in made.values():
            node.close()
        for token in tokens:
            token.undeclare()


def test_gcs_sync_commands_print_offsets_start_and_refuse(router: int, clients, capsys) -> None:
    from bbcs import keys
    from bbcs.contracts import gri
    from bbcs.contracts import tasks as t
    from ral.gcs import cli
    from ral.sync_bus import SyncNode

    clocks = {"uav_a": sync.SkewedClock(offset_s=0.3), "uav_b": sync.SkewedClock(offset_s=-0.2)}
    started: list[str] = []

    def starter(name: str):
        def start(task: t.TaskParams) -> gri.TaskReply:
            started.append(name)
            return gri.TaskReply(accepted=True, task_id=1)
        return start

    refuse: dict[str, str] = {}

    def checker(name: str):
        return lambda task: refuse.get(name)

    sessions = {n: clients(router) for n in clocks}
    tokens = [sessions[n].liveliness().declare_token(keys.alive_key(n, "ral")) for n in clocks]
    made = {n: SyncNode(sessions[n], n, clocks[n], starter(n), checker(n), period_s=0.1) for n in clocks}
    base = ["--connect", f"tcp/127.0.0.1:{router}", "--name", "ground", "--timeout", "10", "sync"]
    try:
        wait_until(lambda: made["uav_b"].tracker.estimate("uav_a") is not None
                   and made["uav_a"].tracker.estimate("uav_b") is not None, 20, "both offsets")
        assert cli.main([*base, "clocks", "uav_b"]) == 0
        out = capsys.readouterr().out.splitlines()
        row = next(line for line in out if line.startswith("uav_a"))
        assert float(row.split()[1]) == pytest.approx(500.0, abs=20.0)  # uav_a − uav_b = 0.5 s, in ms
        assert cli.main([*base, "start", "uav_a", "uav_b", "--task", "hold", "--lead", "1"]) == 0
        shown = capsys.readouterr().out
        assert "start hold at" in shown and "on uav_a's clock" in shown and shown.count("on its own clock") == 2
        wait_until(lambda: sorted(started) == ["uav_a", "uav_b"], 20, "both started")
        first_groups = {x.group for x in made["uav_a"].started}
        assert cli.main([*base, "start", "uav_a", "uav_c", "--lead", "1"]) == 3  # uav_c is not there
        assert "uav_c" in capsys.readouterr().err and len(started) == 2  # nothing was sent
        refuse["uav_b"] = "this robot has no task 'hold'"
        assert cli.main([*base, "start", "uav_a", "uav_b", "--task", "hold", "--lead", "1"]) == 1
        shown = capsys.readouterr().out
        assert "uav_b            REFUSED: this robot has no task 'hold'" in shown, shown
        assert "uav_a            REFUSED: cancelled: another robot refused" in shown, shown
        wait_until(lambda: any(x.group not in first_groups and not x.accepted
                               and x.reason.startswith("cancelled") for x in made["uav_a"].started), 20,
                   "uav_a's cancelled start at its instant")
        assert sorted(started) == ["uav_a", "uav_b"]  # the cancelled one never started
        assert cli.main([*base, "formation", "uav_a", "uav_a"]) == 1
        assert "cannot keep formation on itself" in capsys.readouterr().out
    finally:
        for node in made.values():
            node.close()
        for token in tokens:
            token.undeclare()
