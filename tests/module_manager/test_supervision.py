"""The supervision state machine with an injected clock: policies, backoff, intensity limit, liveliness."""

from __future__ import annotations

import pytest

from bbcs.errors import EXIT_CONFIG
from module_manager.manifest import find_cycle
from module_manager.supervision import (
    Kill,
    Phase,
    Policy,
    Spawn,
    Supervisor,
    backoff_delay,
    launch_gave_up,
    startable,
)


def started(policy: Policy, needs_ack: bool = True, now: float = 0.0) -> Supervisor:
    sup = Supervisor(policy, needs_ack=needs_ack)
    sup.start(now)
    assert sup.tick(now) == [Spawn(restart_count=0)]
    sup.spawned(now)
    return sup


def bring_up(sup: Supervisor, now: float) -> None:
    sup.liveliness(now, True)
    sup.routes_acknowledged(now, True)
    assert sup.phase is Phase.UP


def test_up_needs_alive_and_matching_route_ack_in_any_order():
    sup = started(Policy())
    sup.routes_acknowledged(0.1, True)
    assert sup.phase is Phase.STARTING
    sup.liveliness(0.2, True)
    assert sup.phase is Phase.UP
    other = started(Policy())
    other.liveliness(0.1, True)
    other.routes_acknowledged(0.2, False)
    assert other.phase is Phase.STARTING, "an ack with other routes does not count"
    other.routes_acknowledged(0.3, True)
    assert other.phase is Phase.UP


def test_a_peer_module_is_up_only_once_its_direct_links_formed_and_again_after_a_restart():
    sup = Supervisor(Policy(), needs_ack=True, needs_links=True)
    sup.start(0.0)
    assert sup.tick(0.0) == [Spawn(restart_count=0)]
    sup.spawned(0.0)
    assert not sup.awaiting_links
    sup.liveliness(0.1, True)
    sup.routes_acknowledged(0.2, True)
    assert sup.phase is Phase.STARTING and sup.awaiting_links, "alive and routed, its links not formed yet"
    sup.links_formed(0.3)
    assert sup.phase is Phase.UP and not sup.awaiting_links
    sup.exited(1.0, -9)
    assert sup.tick(1.0) == [Spawn(restart_count=1)]
    sup.spawned(1.0)
    sup.liveliness(1.1, True)
    sup.routes_acknowledged(1.1, True)
    assert sup.phase is Phase.STARTING and sup.awaiting_links, "a new run links again before it counts as up"
    sup.links_formed(1.2)
    assert sup.phase is Phase.UP


def test_a_peer_module_that_never_links_is_killed_at_its_start_timeout_naming_the_links():
    sup = Supervisor(Policy(start_timeout_s=5.0), needs_ack=False, needs_links=True)
    sup.start(0.0)
    sup.tick(0.0)
    sup.spawned(0.0)
    sup.liveliness(0.1, True)
    [kill] = sup.tick(5.1)
    assert isinstance(kill, Kill) and kill.reason == "start timeout: no direct links after 5 s"


def test_module_without_routed_inputs_is_up_when_alive():
    sup = started(Policy(), needs_ack=False)
    sup.liveliness(0.1, True)
    assert sup.phase is Phase.UP


@pytest.mark.parametrize("policy,code,phase", [
    ("never", 1, Phase.FAILED), ("never", 0, Phase.STOPPED), ("never", -9, Phase.FAILED),
    ("on-failure", 0, Phase.STOPPED), ("on-failure", 2, Phase.RESTARTING), ("on-failure", -9, Phase.RESTARTING),
    ("always", 0, Phase.RESTARTING), ("always", 1, Phase.RESTARTING),
])
def test_restart_policies(policy, code, phase):
    sup = started(Policy(restart=policy))
    bring_up(sup, 1.0)
    sup.exited(5.0, code)
    assert sup.phase is phase
    assert sup.last_exit == code
    assert (sup.restarts == 1) == (phase is Phase.RESTARTING)


@pytest.mark.parametrize("policy", ["never", "on-failure", "always"])
def test_configuration_error_exit_is_never_restarted(policy):
    sup = started(Policy(restart=policy, backoff_s=0.1, intensity=5))
    sup.exited(0.5, EXIT_CONFIG)
    assert sup.phase is Phase.FAILED
    assert sup.restarts == 0
    assert "configuration error" in sup.reason and "78" in sup.reason
    assert sup.tick(100.0) == [], "no spawn, however long we wait"


def test_exponential_backoff_with_cap():
    sup = started(Policy(restart="always", backoff_s=0.5, backoff_max_s=3.0, intensity=100, period_s=1000))
    now = 0.0
    delays = []
    for run in range(1, 7):
        sup.exited(now, 1)
        assert sup.next_start_at is not None
        delay = sup.next_start_at - now
        delays.append(delay)
        if delay > 0:
            assert sup.tick(now + delay - 0.01) == [], "not before the backoff delay"
        now += delay
        assert sup.tick(now) == [Spawn(restart_count=run)]
        sup.spawned(now)
    assert delays == [0.0, 0.5, 1.0, 2.0, 3.0, 3.0], "the first failure in the window restarts at once"


def test_sigkilled_module_is_respawned_on_the_same_tick_without_backoff():
    sup = started(Policy(restart="on-failure", backoff_s=2.0, intensity=5, period_s=10))
    bring_up(sup, 0.0)
    sup.exited(30.0, -9)
    assert sup.phase is Phase.RESTARTING and sup.reason == "killed by signal 9; restart in 0 s"
    assert sup.tick(30.0) == [Spawn(restart_count=1)], "no waiting for a first failure"
    sup.spawned(30.0)
    bring_up(sup, 30.2)
    sup.exited(31.0, -9)  # a second failure inside the window: now the backoff applies
    assert sup.tick(31.0) == [] and sup.next_start_at == 33.0
    assert sup.tick(33.0) == [Spawn(restart_count=2)]
    sup.spawned(33.0)
    bring_up(sup, 33.1)
    sup.exited(50.0, -9)  # the earlier restarts left the window: a first failure again
    assert sup.tick(50.0) == [Spawn(restart_count=3)]


def test_backoff_delay_rule():
    p = Policy(backoff_s=0.5, backoff_max_s=3.0)
    assert [backoff_delay(p, n) for n in range(6)] == [0.0, 0.5, 1.0, 2.0, 3.0, 3.0]


def test_intensity_limit_marks_failed_and_stops_restarting():
    sup = started(Policy(restart="always", backoff_s=0.1, intensity=3, period_s=10))
    now = 0.0
    for _ in range(3):
        sup.exited(now, 1)
        now = sup.next_start_at
        assert sup.tick(now)
        sup.spawned(now)
        bring_up(sup, now)  # counted even after a good start (supervisord's gap)
    sup.exited(now, 1)
    assert sup.phase is Phase.FAILED
    assert "intensity" in sup.reason
    assert sup.tick(now + 100) == []
    assert sup.restarts == 3


def test_restarts_outside_the_window_do_not_count():
    sup = started(Policy(restart="on-failure", backoff_s=0.1, intensity=2, period_s=10))
    now = 0.0
    for _ in range(5):
        sup.exited(now, 1)
        assert sup.phase is Phase.RESTARTING
        now = sup.next_start_at
        sup.tick(now)
        sup.spawned(now)
        now += 11.0  # each crash more than period_s after the previous restart
    assert sup.restarts == 5


def test_start_timeout_kills_and_counts_as_failure():
    sup = started(Policy(restart="on-failure", start_timeout_s=5))
    sup.liveliness(1.0, True)
    assert sup.tick(4.0) == []
    actions = sup.tick(5.5)
    assert actions == [Kill(reason="start timeout: no route acknowledgement after 5 s", graceful=False)]
    assert sup.tick(5.6) == [], "one kill per run"
    sup.exited(5.7, -9)
    assert sup.phase is Phase.RESTARTING


def test_killed_start_that_exits_zero_still_counts_as_failure():
    sup = started(Policy(restart="on-failure", start_timeout_s=1))
    assert sup.tick(2.0)
    sup.exited(2.1, 0)
    assert sup.phase is Phase.RESTARTING


def test_liveliness_delete_alone_is_unreachable_after_debounce_never_a_restart():
    sup = started(Policy(unreachable_debounce_s=1.0))
    bring_up(sup, 0.0)
    sup.liveliness(10.0, False)
    assert sup.tick(10.5) == [] and not sup.unreachable
    sup.liveliness(10.6, True)  # a flap (router restart): nothing reported
    assert sup.tick(12.0) == [] and not sup.unreachable
    sup.liveliness(20.0, False)
    assert sup.tick(21.5) == []
    assert sup.unreachable and sup.phase is Phase.UP
    sup.liveliness(22.0, True)
    assert not sup.unreachable


def test_watchdog_kills_a_silent_module():
    sup = started(Policy(watchdog_s=3.0))
    bring_up(sup, 0.0)
    sup.heartbeat(1.0)
    assert sup.tick(3.9) == []
    assert sup.tick(4.1) == [Kill(reason="watchdog: no heartbeat for 3 s", graceful=False)]


def test_operator_stop_restart_start():
    sup = started(Policy(restart="always"))
    bring_up(sup, 0.0)
    assert sup.stop(1.0) == [Kill(reason="stopped by request", graceful=True)]
    sup.exited(1.2, 0)
    assert sup.phase is Phase.STOPPED and sup.restarts == 0, "a requested stop is never restarted"
    sup.start(2.0)
    assert sup.tick(2.0) == [Spawn(restart_count=1)]
    sup.spawned(2.0)
    bring_up(sup, 2.1)
    assert sup.restart(3.0) == [Kill(reason="restart requested", graceful=True)]
    assert sup.state == "restarting"
    sup.exited(3.1, -15)
    assert sup.tick(3.1) == [Spawn(restart_count=2)]
    assert sup.restarts == 0


def test_failed_module_can_be_started_again_by_the_operator():
    sup = started(Policy(restart="never"))
    sup.exited(1.0, 1)
    assert sup.phase is Phase.FAILED
    sup.start(2.0)
    assert sup.tick(2.0) == [Spawn(restart_count=1)]
    assert sup.reason == ""


AFTER = {"dsp": (), "follower": ("dsp",), "gcs_link": ("dsp", "follower"), "logger": ("sim",)}
"""A start graph: ``sim`` is a process (ready before any module starts), the others are modules."""


def phases(**given: Phase) -> dict[str, Phase]:
    return {name: given.get(name, Phase.STOPPED) for name in AFTER}


def test_modules_without_dependencies_start_together_dependents_wait_until_up():
    waiting = set(AFTER)
    start, blocked = startable(waiting, AFTER, phases())
    assert start == ["dsp", "logger"] and blocked == {}, "a process dependency does not hold a module back"
    waiting -= set(start)
    assert startable(waiting, AFTER, phases(dsp=Phase.STARTING, logger=Phase.STARTING)) == ([], {})
    start, _ = startable(waiting, AFTER, phases(dsp=Phase.UP, logger=Phase.STARTING))
    assert start == ["follower"], "gcs_link also waits for follower"
    waiting -= {"follower"}
    start, _ = startable(waiting, AFTER, phases(dsp=Phase.UP, follower=Phase.UP))
    assert start == ["gcs_link"]


def test_dependency_that_failed_blocks_its_dependents_with_a_reason():
    start, blocked = startable({"follower", "gcs_link"}, AFTER, phases(dsp=Phase.FAILED))
    assert start == []
    assert blocked == {"follower": "not started: it starts after dsp (dsp failed)",
                       "gcs_link": "not started: it starts after dsp (dsp failed)"}
    _, later = startable({"gcs_link"}, AFTER, phases(dsp=Phase.UP, follower=Phase.STOPPED))
    assert later == {"gcs_link": "not started: it starts after follower (follower stopped)"}
    sup = Supervisor(Policy())
    sup.blocked(blocked["follower"])
    assert sup.phase is Phase.FAILED and sup.tick(100.0) == [], "never spawned by itself"
    sup.start(101.0)
    assert sup.tick(101.0) == [Spawn(restart_count=0)], "an operator may still start it"


def test_find_cycle():
    assert find_cycle({"a": ["b"], "b": ["c"], "c": []}) == []
    assert find_cycle({"a": ["b"], "b": ["c"], "c": ["a"]}) == ["a", "b", "c", "a"]
    assert find_cycle({"x": [], "a": ["b"], "b": ["b"]}) == ["b", "b"]


def test_a_launch_gives_up_only_when_every_module_settled_and_one_is_down() -> None:
    assert not launch_gave_up([Phase.UP, Phase.UP]), "every module up is the robot up, not a failure"
    assert launch_gave_up([Phase.UP, Phase.FAILED])
    assert launch_gave_up([Phase.STOPPED, Phase.UP])
    assert not launch_gave_up([Phase.FAILED, Phase.STARTING]), "one still starting may yet come up"
    assert not launch_gave_up([Phase.UP, Phase.RESTARTING])
