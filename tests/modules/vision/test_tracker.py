"""Lost-target hysteresis, driven by an injected clock (frame times chosen by the test)."""

import pytest

from modules.vision.tracker import TargetTracker, TrackerConfig, TrackState

LOST, TENTATIVE, FOUND = TrackState.LOST, TrackState.TENTATIVE, TrackState.FOUND
CFG = TrackerConfig(confidence_on=0.5, confidence_off=0.3, confirm_hits=3, confirm_s=0.1, lose_s=1.0)


def run(tracker, steps):
    """steps: (time, confidence-or-None); returns the states."""
    return [tracker.update(conf, t) for t, conf in steps]


def test_acquire_needs_consistent_hits_and_time():
    tr = TargetTracker(CFG)
    assert run(tr, [(0.0, 0.9), (0.04, 0.9), (0.08, 0.9), (0.12, 0.9)]) == [TENTATIVE, TENTATIVE, TENTATIVE, FOUND]


def test_three_fast_hits_are_not_enough_before_confirm_time():
    tr = TargetTracker(CFG)
    assert run(tr, [(0.0, 0.9), (0.01, 0.9), (0.02, 0.9)]) == [TENTATIVE] * 3
    assert tr.update(0.9, 0.1) is FOUND


def test_a_miss_while_tentative_drops_back_to_lost():
    tr = TargetTracker(CFG)
    assert run(tr, [(0.0, 0.9), (0.05, None), (0.1, 0.9)]) == [TENTATIVE, LOST, TENTATIVE]
    assert run(tr, [(0.15, 0.4)]) == [LOST]  # below confidence_on counts as a miss before FOUND


def test_weak_detections_keep_a_found_target_but_cannot_acquire_one():
    tr = TargetTracker(CFG)
    assert run(tr, [(0.0, 0.4), (0.1, 0.4), (0.2, 0.4)]) == [LOST] * 3
    run(tr, [(1.0, 0.9), (1.05, 0.9), (1.1, 0.9)])
    assert tr.state is FOUND
    assert run(tr, [(1.2 + 0.1 * k, 0.35) for k in range(30)]) == [FOUND] * 30
    assert tr.hit and not tr.coasting


def test_found_survives_dropouts_shorter_than_lose_time():
    tr = TargetTracker(CFG)
    run(tr, [(0.0, 0.9), (0.05, 0.9), (0.1, 0.9)])
    assert run(tr, [(0.5, None), (1.09, 0.1)]) == [FOUND, FOUND]
    assert tr.coasting
    assert tr.update(0.6, 1.1) is FOUND and tr.last_hit == 1.1
    assert run(tr, [(1.5, None), (2.0, None), (2.09, None), (2.1, None)]) == [FOUND, FOUND, FOUND, LOST]
    assert not tr.coasting


def test_reacquire_after_loss_starts_again_from_tentative():
    tr = TargetTracker(CFG)
    run(tr, [(0.0, 0.9), (0.05, 0.9), (0.1, 0.9), (1.1, None)])
    assert tr.state is LOST
    assert run(tr, [(1.2, 0.9), (1.25, 0.9), (1.3, 0.9)]) == [TENTATIVE, TENTATIVE, FOUND]


def test_single_hit_config_acquires_at_once():
    tr = TargetTracker(TrackerConfig(confirm_hits=1, confirm_s=0.0))
    assert tr.update(0.8, 5.0) is FOUND


def test_time_must_not_go_backwards_and_inputs_are_checked():
    tr = TargetTracker(CFG)
    tr.update(0.9, 10.0)
    with pytest.raises(ValueError, match="backwards"):
        tr.update(0.9, 9.0)
    with pytest.raises(ValueError):
        tr.update(1.5, 11.0)
    with pytest.raises(ValueError):
        tr.update(0.5, float("nan"))
    tr.reset()
    assert tr.state is LOST and tr.update(0.9, 0.0) is TENTATIVE


@pytest.mark.parametrize(
    "kwargs",
    [dict(confidence_on=0.2, confidence_off=0.3), dict(confirm_hits=0), dict(lose_s=0.0), dict(confidence_on=1.5)],
)
def test_bad_tracker_config(kwargs):
    with pytest.raises(ValueError):
        TrackerConfig(**kwargs)
