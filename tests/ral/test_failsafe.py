"""The link-loss failsafe as a pure state machine with an injected clock."""

from __future__ import annotations

import pytest

from ral.failsafe import FailsafeAction, FailsafeConfig, LinkMonitor

CFG = FailsafeConfig(loss_timeout_s=10.0, heartbeat_timeout_s=2.0, regain_s=1.0, action=FailsafeAction.RETURN)


def linked(now: float = 0.0) -> LinkMonitor:
    m = LinkMonitor(CFG)
    m.token("gcs", True)
    m.heartbeat(now)
    assert [e.kind for e in m.update(now)] == ["link_up"]
    return m


def kinds(events) -> list[str]:
    return [e.kind for e in events]


def test_nothing_is_armed_before_the_first_link() -> None:
    m = LinkMonitor(CFG)
    for t in range(0, 100, 5):
        assert m.update(float(t)) == []
    assert m.state == "no_gcs"


def test_token_without_heartbeat_is_not_a_link() -> None:
    m = LinkMonitor(CFG)
    m.token("gcs", True)
    assert m.update(0.0) == []
    m.heartbeat(0.5)
    assert kinds(m.update(0.5)) == ["link_up"]


def test_token_loss_then_timeout_runs_the_action_once() -> None:
    m = linked()
    m.token("gcs", False)
    ev = m.update(1.0)
    assert kinds(ev) == ["link_lost"] and "liveliness" in ev[0].detail
    assert m.update(10.9) == []
    ev = m.update(11.0)
    assert kinds(ev) == ["failsafe"] and ev[0].action is FailsafeAction.RETURN
    assert m.update(12.0) == [] and m.update(100.0) == []
    assert m.state == "failsafe"


def test_heartbeat_silence_counts_as_loss_even_with_a_token() -> None:
    m = linked()
    m.heartbeat(1.0)
    assert m.update(3.0) == []  # 2.0 s since the last heartbeat: still up
    ev = m.update(3.1)
    assert kinds(ev) == ["link_lost"] and "heartbeat" in ev[0].detail
    assert kinds(m.update(13.1)) == ["failsafe"]


def test_regained_before_timeout_needs_hysteresis_and_runs_nothing() -> None:
    m = linked()
    m.token("gcs", False)
    m.update(1.0)
    m.token("gcs", True)
    m.heartbeat(5.0)
    assert m.update(5.0) == []  # link back, not yet for regain_s
    m.heartbeat(5.9)
    assert m.update(5.9) == []
    m.heartbeat(6.0)
    ev = m.update(6.0)
    assert kinds(ev) == ["link_regained"] and "unchanged" in ev[0].detail
    assert m.state == "up"


def test_a_flapping_link_keeps_the_original_loss_time() -> None:
    m = linked()
    m.token("gcs", False)
    m.update(1.0)
    m.token("gcs", True)
    m.heartbeat(5.0)
    m.update(5.0)
    m.token("gcs", False)
    assert m.update(5.5) == []  # lost again before regain_s: still counting from 1.0
    assert kinds(m.update(11.0)) == ["failsafe"]


def test_regaining_after_the_failsafe_does_not_resume() -> None:
    m = linked()
    m.token("gcs", False)
    m.update(0.5)
    assert kinds(m.update(10.5)) == ["failsafe"]
    m.token("gcs2", True)
    m.heartbeat(20.0)
    assert m.update(20.0) == []
    m.heartbeat(21.0)
    ev = m.update(21.0)
    assert kinds(ev) == ["link_regained"] and "stays in force" in ev[0].detail
    assert all(e.action is None for e in ev)
    m.token("gcs2", False)
    assert kinds(m.update(22.0)) == ["link_lost"]
    assert kinds(m.update(32.0)) == ["failsafe"]


def test_any_one_gcs_keeps_the_link() -> None:
    m = linked()
    m.token("backup", True)
    m.token("gcs", False)
    m.heartbeat(1.0)
    assert m.update(1.0) == [] and m.state == "up"


@pytest.mark.parametrize("field", ["loss_timeout_s", "heartbeat_timeout_s", "regain_s"])
def test_negative_times_are_refused(field: str) -> None:
    with pytest.raises(ValueError, match=field):
        FailsafeConfig(**{field: -1.0})


def test_unknown_action_is_refused() -> None:
    with pytest.raises(ValueError):
        FailsafeConfig(action="explode")  # type: ignore[arg-type]


def test_an_operator_task_ends_the_failsafe_and_nothing_is_armed_until_a_new_link() -> None:
    m = linked()
    m.token("gcs", False)
    m.update(1.0)
    assert kinds(m.update(11.0)) == ["failsafe"] and m.in_force
    assert m.clear_failsafe() and not m.in_force and m.state == "no_gcs"
    for t in range(12, 100, 5):  # the operator holds no link: no second failsafe
        assert m.update(float(t)) == []
    m.token("pilot", True)
    m.heartbeat(100.0)
    assert kinds(m.update(100.0)) == ["link_up"]  # a new link arms it again


def test_clearing_changes_nothing_outside_a_failsafe() -> None:
    m = linked()
    assert not m.clear_failsafe() and m.state == "up"
    m.token("gcs", False)
    m.update(1.0)
    assert not m.clear_failsafe() and m.state == "lost"  # a loss still counts towards its failsafe
    assert kinds(m.update(11.0)) == ["failsafe"]
