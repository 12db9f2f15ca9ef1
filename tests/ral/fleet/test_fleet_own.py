"""A robot's own bid state from the RAL's view: the battery it bids with comes from its telemetry's pack voltage,
its busy time from the rest of the path it is flying for someone else."""

from __future__ import annotations

import pytest

from bbcs.contracts import tasks as t
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.contracts.tasks import TaskInfo, Waypoint
from ral.allocation import Bid, Target, allocate
from ral.fleet import BUSY_DEFAULT_S, busy_seconds, own_state_of, state_of_charge

PACK = (19.8, 25.2)


def test_state_of_charge_is_linear_between_the_pack_voltages_and_clamped() -> None:
    assert state_of_charge(25.2, *PACK) == 1.0
    assert state_of_charge(19.8, *PACK) == 0.0
    assert state_of_charge(23.4, *PACK) == pytest.approx(2 / 3)
    assert state_of_charge(26.0, *PACK) == 1.0 and state_of_charge(12.0, *PACK) == 0.0
    assert state_of_charge(None, *PACK) is None


def telemetry(volts: float | None) -> RobotTelemetry:
    return RobotTelemetry(stamp=1.0, position=GeoPoint(lat=37.4, lon=-6.0, alt=30.0), battery_v=volts)


def test_the_bid_carries_the_state_of_charge_only_where_the_pack_is_known() -> None:
    assert own_state_of(telemetry(23.4), 5.0, frozenset({"visit"}), [], pack_v=PACK).battery == pytest.approx(2 / 3)
    assert own_state_of(telemetry(23.4), 5.0, frozenset({"visit"}), []).battery is None  # no pack in the manifest
    assert own_state_of(telemetry(None), 5.0, frozenset({"visit"}), [], pack_v=PACK).battery is None
    assert own_state_of(None, 5.0, frozenset({"visit"}), [], pack_v=PACK).battery is None


def test_a_nearer_robot_on_a_low_pack_loses_the_target_to_a_farther_full_one() -> None:
    low = own_state_of(telemetry(20.1), 5.0, frozenset({"visit"}), [], pack_v=PACK).battery
    full = own_state_of(telemetry(25.2), 5.0, frozenset({"visit"}), [], pack_v=PACK).battery
    target = [Target("t", 0.0, 0.0)]
    got = allocate(target, [Bid("near", 100.0, 0.0, battery=low), Bid("far", -150.0, 0.0, battery=full)])
    assert list(got.routes["far"]) == ["t"] and not got.routes["near"]
    unknown = allocate(target, [Bid("near", 100.0, 0.0), Bid("far", -150.0, 0.0)])
    assert list(unknown.routes["near"]) == ["t"]  # the control: without the battery the nearer robot wins


def info(params: object, origin: str = "gri", kind: str = "goto") -> TaskInfo:
    return TaskInfo(id=1, name=kind, task_type="movement", kind=kind, params=params, origin=origin)


def test_busy_time_is_the_rest_of_the_path_at_its_speed() -> None:
    here = GeoPoint(lat=37.4, lon=-6.0, alt=30.0)
    north = [Waypoint(lat=37.4 + k * 1e-3, lon=-6.0, alt=30.0) for k in (1, 2, 3)]  # 111 m legs
    goto = t.Goto(waypoints=north, speed=5.0)
    assert busy_seconds(info(goto), here, 3.0) == pytest.approx(333.6 / 5.0, rel=1e-2)  # at its start: the whole
    mid = GeoPoint(lat=37.4015, lon=-6.0, alt=30.0)  # past the first waypoint, on the second leg
    assert busy_seconds(info(goto), mid, 3.0) == pytest.approx(166.8 / 5.0, rel=1e-2)
    slow = t.Goto(waypoints=north)  # no speed of its own: the robot's
    assert busy_seconds(info(slow), here, 3.0) == pytest.approx(333.6 / 3.0, rel=1e-2)
    assert busy_seconds(info(t.TakeOff(height=10.0), kind="take_off"), here, 3.0) == BUSY_DEFAULT_S


def test_the_bid_counts_only_movement_the_fleet_did_not_give() -> None:
    goto = t.Goto(waypoints=[Waypoint(lat=37.401, lon=-6.0, alt=30.0)], speed=5.0)
    tel = telemetry(25.2)
    assert own_state_of(tel, 5.0, frozenset({"visit"}), [info(goto)]).busy_s == pytest.approx(111.2 / 5.0, rel=1e-2)
    assert own_state_of(tel, 5.0, frozenset({"visit"}), [info(goto, origin="fleet")]).busy_s == 0.0
    assert own_state_of(tel, 5.0, frozenset({"visit"}), [info(t.Hold(), kind="hold")]).busy_s == 0.0
