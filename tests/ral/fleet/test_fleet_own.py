"""A robot's own bid state from the RAL's view: the battery it bids with comes from its telemetry's pack voltage."""

from __future__ import annotations

import pytest

from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from ral.allocation import Bid, Target, allocate
from ral.fleet import own_state_of, state_of_charge

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
