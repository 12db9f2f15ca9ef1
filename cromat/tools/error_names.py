"""Names of error codes by source module (docs/error_codes.md), for tools that show errors to people.

Each module's codes live in its own enum; this table only points at them. An unknown code is shown as its
number.
"""

from __future__ import annotations

import functools
import importlib
from enum import IntEnum

from bbcs.errors import BusErrorCode

# source module name → "package.module:Enum" of its codes 100 and up
MODULE_CODES: dict[str, str] = {
    "pan_tilt": "modules.pan_tilt.logic:PanTiltError",
    "path_follower": "modules.path_follower.logic:FollowerError",
    "vision": "modules.vision.process:VisionErrorCode",
    "dsp": "modules.dsp.errors:LinkErrorCode",
    "ral": "ral.process:RalErrorCode",
}
DSP_FORWARDED = 1000
"""1000 + n: DSP error n forwarded by the module whose command the DSP refused."""


@functools.cache
def _enum(source: str) -> type[IntEnum] | None:
    where = MODULE_CODES.get(source)
    if where is None:
        return None
    module, _, name = where.partition(":")
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError):
        return None


def error_name(source: str, code: int) -> str:
    """``OUT_OF_RANGE``, ``SPEED_ABOVE_MAX``, ``DSP_WRONG_MODE``... or ``""`` when the code is not known."""
    if 0 < code < 100:
        try:
            return BusErrorCode(code).name
        except ValueError:
            return ""
    if code >= DSP_FORWARDED:
        try:
            from modules.dsp.protocol import ErrorCode

            return "DSP_" + ErrorCode(code - DSP_FORWARDED).name
        except (ImportError, ValueError):
            return ""
    enum = _enum(source)
    if enum is None:
        return ""
    try:
        return enum(code).name
    except ValueError:
        return ""
