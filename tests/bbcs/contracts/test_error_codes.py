"""The error-code contract: every module's codes in one registry, named the same way by every tool."""

from __future__ import annotations

import pytest

from bbcs.contracts.dsp import FORWARDED_DSP_ERROR_BASE, ErrorCode, LinkErrorCode
from bbcs.contracts.error_codes import MODULE_CODES, FollowerError, PanTiltError, RalErrorCode, error_name
from bbcs.errors import BusErrorCode


@pytest.mark.parametrize(("module", "code", "name"), [
    ("pan_tilt", 1, "OUT_OF_RANGE"),  # bus codes mean the same in every module
    ("anything", int(BusErrorCode.MALFORMED), "MALFORMED"),
    ("pan_tilt", int(PanTiltError.REF_PAN_OUT_OF_RANGE), "REF_PAN_OUT_OF_RANGE"),
    ("path_follower", int(FollowerError.SPEED_ABOVE_MAX), "SPEED_ABOVE_MAX"),
    ("path_follower", 119, "OFF_PATH"),  # mode 3's codes are the path follower's too
    ("ral", int(RalErrorCode.TASK_FAILED), "TASK_FAILED"),
    ("dsp", int(LinkErrorCode.NOT_OWNER), "NOT_OWNER"),
    ("path_follower", FORWARDED_DSP_ERROR_BASE + ErrorCode.WRONG_MODE, "DSP_WRONG_MODE"),
    ("path_follower", FORWARDED_DSP_ERROR_BASE + LinkErrorCode.FLUSHED, "DSP_FLUSHED"),
])
def test_known_codes_are_named(module: str, code: int, name: str) -> None:
    assert error_name(module, code) == name


@pytest.mark.parametrize(("module", "code"), [("pan_tilt", 0), ("pan_tilt", 99), ("pan_tilt", 150),
                                              ("unknown_module", 100), ("dsp", 1999)])
def test_unknown_codes_have_no_name(module: str, code: int) -> None:
    assert error_name(module, code) == ""


def test_module_codes_stay_in_the_module_range() -> None:
    """100-999 belong to the module: none of its codes may collide with the bus's or the forwarded DSP's."""
    for module, enum in MODULE_CODES.items():
        assert all(100 <= int(m) < FORWARDED_DSP_ERROR_BASE for m in enum), module

