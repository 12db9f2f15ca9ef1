"""RAL parameters from the manifest: unknown names and values that would break the MRI contract are refused."""

from __future__ import annotations

import pytest

from bbcs.conf import ConfError
from bbcs.contracts import mri
from ral.config import RalConfig


def test_defaults_wait_longer_for_the_manager_than_it_waits_for_modules() -> None:
    cfg, names = RalConfig.from_params({"task.goto": "goto"})
    assert cfg.mri_timeout_s == mri.REPLY_TIMEOUT_S > mri.MANAGER_ACK_S
    assert names == {"goto": "goto"}


def test_mri_timeout_not_above_the_manager_ack_wait_is_refused() -> None:
    with pytest.raises(ValueError, match="mri_timeout_s = 5 must exceed the manager's ack wait"):
        RalConfig.from_params({"mri_timeout_s": str(mri.MANAGER_ACK_S)})
    cfg, _ = RalConfig.from_params({"mri_timeout_s": "6"})
    assert cfg.mri_timeout_s == 6.0


def test_unknown_parameter_is_named() -> None:
    with pytest.raises(ValueError, match="mri_timeuot_s: unknown RAL parameter .did you mean mri_timeout_s"):
        RalConfig.from_params({"mri_timeuot_s": "8"})


def test_every_bad_parameter_is_named_at_once_and_is_a_configuration_error() -> None:  # issue 30 case 8
    params = {"failsafe_action": "retrun", "stal_s": "30", "settle_s": "soon", "task.goto": "goto", "kind": "uav"}
    assert RalConfig.param_errors(params) == [
        ("failsafe_action", "bad value 'retrun': Invalid enum value 'retrun' (one of: hold, return, land)"),
        ("stal_s", "unknown RAL parameter (did you mean stall_s? known: " + ", ".join(RalConfig.__struct_fields__)
         + ")"),
        ("settle_s", "bad value 'soon': Expected `float`, got `str`"),
    ]
    with pytest.raises(ConfError) as exc:  # the RAL exits EXIT_CONFIG: the manager does not restart it
        RalConfig.from_params(params)
    assert "failsafe_action" in str(exc.value) and "stal_s" in str(exc.value) and "settle_s" in str(exc.value)
    assert RalConfig.param_errors({"failsafe_action": "land", "stall_s": "30", "zzz": "1"}) == [
        ("zzz", "unknown RAL parameter (known: " + ", ".join(RalConfig.__struct_fields__) + ")")]
    assert RalConfig.param_errors({"mri_timeout_s": "1"})[0][0] == "mri_timeout_s"


def test_battery_voltages_come_in_a_pair_with_empty_below_full() -> None:
    cfg, _ = RalConfig.from_params({"battery_full_v": "25.2", "battery_empty_v": "19.8"})
    assert (cfg.battery_empty_v, cfg.battery_full_v) == (19.8, 25.2)
    for bad in ({"battery_full_v": "19.8", "battery_empty_v": "25.2"}, {"battery_empty_v": "19.8"},
                {"battery_full_v": "25.2", "battery_empty_v": "-1"}, {"battery_full_v": "250", "battery_empty_v": "1"}):
        with pytest.raises(ValueError, match="battery_empty_v = .* must be volts with 0 <= empty < full <= 100"):
            RalConfig.from_params(bad)
