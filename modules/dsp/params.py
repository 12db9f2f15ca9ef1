"""The DSP module's manifest ``params``: one struct, checked by ``cromat launch --check`` (``DspModule.param_errors``)
and loaded by the module through the same function (``bbcs.params``), so the two never disagree."""

from __future__ import annotations

import msgspec

from bbcs import load_params, struct_param_errors


class DspParams(msgspec.Struct, frozen=True, kw_only=True):
    """What a manifest may set on the DSP module."""

    port: str = ""
    """Serial device or pyserial URL (``/dev/ttyUSB0``, ``socket://HOST:PORT`` for the simulator), opened at
    start-up (a bad one is a link failure, exit 3); empty: the .conf's ``DSP_PORT``."""


def dsp_param_errors(params: dict[str, str]) -> list[tuple[str, str]]:
    """Every problem of the manifest's DSP ``params``, (key, reason)."""
    return struct_param_errors(DspParams, params, what="dsp")


def load_dsp_params(params: dict[str, str]) -> DspParams:
    """The DSP's params, or a ``ParamError`` (a ``ConfError``: exit 78, not restarted) naming every problem."""
    return load_params(DspParams, params, what="dsp")
