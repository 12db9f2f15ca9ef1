"""The ground station's fleet input and the RAL's translation of a share: bad input is refused with a message
naming the target, a share becomes an ordinary goto through its targets in order."""

from __future__ import annotations

import msgspec
import pytest

from bbcs.contracts import tasks as t
from bbcs.contracts.fleet import FleetTarget, FleetTask
from ral.fleet import can_do_from, goto_of
from ral.fleet_gcs import parse_target
from ral.fleet_protocol import Execute


def test_targets_parse_with_kind_and_a_deadline_from_now() -> None:
    x = parse_target("t1, 37.41, -6.0, 22, inspect, 60", 0, now=1000.0)
    assert (x.id, x.lat, x.lon, x.alt, x.kind, x.deadline) == ("t1", 37.41, -6.0, 22.0, "inspect", 1060.0)
    assert parse_target("t2,37.41,-6.0,22", 1, now=0.0).kind == "visit"


@pytest.mark.parametrize("text, why", [
    ("t1,37.41,-6.0", "expected ID,LAT,LON,ALT"),
    ("t1,91,-6.0,22", "--target 1 't1,91,-6.0,22'"),
    ("t/1,37.41,-6.0,22", "--target 1"),
    ("t1,north,-6.0,22", "could not convert"),
])
def test_bad_targets_are_refused_naming_which(text: str, why: str) -> None:
    with pytest.raises(ValueError, match=why):
        parse_target(text, 0, now=0.0)


def test_a_task_without_targets_or_with_a_bad_id_does_not_decode() -> None:
    with pytest.raises(msgspec.ValidationError):
        msgspec.convert({"id": "a b", "targets": [{"id": "t", "lat": 1, "lon": 1, "alt": 1}]}, FleetTask)
    with pytest.raises(msgspec.ValidationError):
        msgspec.convert({"id": "a", "targets": []}, FleetTask)


def test_a_share_is_a_goto_through_its_targets_in_order() -> None:
    a = FleetTarget(id="a", lat=37.0, lon=-6.0, alt=20.0)
    b = FleetTarget(id="b", lat=37.1, lon=-6.1, alt=25.0)
    goto = goto_of(Execute(task=FleetTask(id="x", targets=[a, b], speed=4.0), round=2, targets=(b, a)))
    assert goto == t.Goto(waypoints=[t.Waypoint(lat=37.1, lon=-6.1, alt=25.0), t.Waypoint(lat=37.0, lon=-6.0,
                                                                                         alt=20.0)], speed=4.0)


def test_what_a_robot_bids_on() -> None:
    assert can_do_from("", ["goto", "land"]) == {"visit"}
    assert can_do_from("", ["land"]) == frozenset()
    assert can_do_from("visit, inspect", []) == {"visit", "inspect"}
    assert can_do_from("none", ["goto"]) == frozenset()
