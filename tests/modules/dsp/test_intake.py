"""The DSP process's bounded command intake (modules/dsp/intake.py), with the time passed in."""

from __future__ import annotations

from modules.dsp.intake import CommandIntake

ANGLES = ("SetPanTiltAngles",)
WAYPOINT = ("AddWaypoint",)


def test_a_set_point_flood_is_coalesced_to_one_waiting_batch() -> None:
    intake = CommandIntake(bound=4)
    for i in range(100_000):
        intake.offer("pan_tilt", i, ANGLES)
    assert len(intake) == 1 and intake.take() == ("pan_tilt", 99_999)  # only the newest set-point is sent
    assert intake.total_coalesced == 99_999


def test_different_set_points_are_not_merged() -> None:
    intake = CommandIntake(bound=4)
    intake.offer("pan_tilt", "mode", ("SetPanTiltMode",))
    intake.offer("pan_tilt", "angles", ANGLES)
    assert [intake.take(), intake.take()] == [("pan_tilt", "mode"), ("pan_tilt", "angles")]


def test_other_senders_are_bounded_by_dropping_never_reordered() -> None:
    intake = CommandIntake(bound=3)
    for i in range(10):
        intake.offer("path_follower", i, WAYPOINT)
    assert [intake.take() for _ in range(4)] == [("path_follower", 0), ("path_follower", 1), ("path_follower", 2),
                                                   None]
    assert intake.total_dropped == 7


def test_abort_is_never_lost_and_goes_first_whatever_is_waiting() -> None:
    intake = CommandIntake(bound=2)
    for i in range(5):
        intake.offer("path_follower", i, WAYPOINT)
        intake.offer("pan_tilt", i, ANGLES)
    flushed = intake.offer("path_follower", "ABORT", ("Abort",), abort=True)
    assert sorted(map(str, flushed)) == ["0", "1", "4"]  # the waiting ones (two waypoints, the newest angles)
    assert intake.take() == ("path_follower", "ABORT") and intake.take() is None
    intake.offer("path_follower", "after", WAYPOINT)  # a sender is not blocked by what the abort flushed
    assert intake.take() == ("path_follower", "after")


def test_losses_are_reported_once_a_window_per_sender_with_their_counts() -> None:
    intake = CommandIntake(bound=1, window_s=1.0)
    assert intake.refuse("pan_tilt", 0.0)  # the first refusal of a window: reported in full at once
    for i in range(1000):
        intake.offer("pan_tilt", i, ANGLES)
        intake.offer("path_follower", i, WAYPOINT)
        assert not intake.refuse("pan_tilt", 0.1)
    first = intake.due(0.5)
    assert [(f.sender, f.coalesced, f.dropped, f.refused) for f in first] == [("path_follower", 0, 999, 0)]
    assert intake.due(0.6) == []  # nothing new for path_follower, pan_tilt's window not over
    later = intake.due(1.0)
    assert [(f.sender, f.coalesced, f.refused) for f in later] == [("pan_tilt", 999, 1000)]
    assert intake.due(5.0) == []


def test_set_points_superseded_at_the_vision_rate_are_no_flood_and_are_forgotten() -> None:
    intake = CommandIntake(bound=4, window_s=1.0, flood_batches=50)
    for second in range(5):  # 10 Hz while a path upload holds the line: each angle supersedes the waiting one
        for i in range(10):
            intake.offer("pan_tilt", i, ANGLES)
            assert intake.due(second + i / 10) == []
        intake.take()
    assert intake.total_coalesced == 45  # counted, never reported


def test_a_flood_of_superseded_set_points_is_reported_at_its_threshold() -> None:
    intake = CommandIntake(bound=4, window_s=1.0, flood_batches=50)
    reports = []
    for i in range(51):  # the first waits, the next 50 supersede it
        intake.offer("pan_tilt", i, ANGLES)
        reports += intake.due(i / 1000)
    assert [(f.sender, f.coalesced) for f in reports] == [("pan_tilt", 50)]


def test_a_single_drop_is_reported() -> None:
    intake = CommandIntake(bound=1, window_s=1.0, flood_batches=50)
    intake.offer("path_follower", 0, WAYPOINT)
    intake.offer("path_follower", 1, WAYPOINT)
    assert [(f.sender, f.dropped) for f in intake.due(0.0)] == [("path_follower", 1)]
