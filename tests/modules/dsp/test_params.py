"""The DSP module's manifest params: the hook ``cromat launch --check`` calls and the module's own load agree."""

from __future__ import annotations

import pytest

from bbcs.params import ParamError
from modules.dsp.module import DspModule
from modules.dsp.params import DspParams, load_dsp_params


def test_shipped_port_param_is_accepted_and_loaded() -> None:
    shipped = {"port": "socket://127.0.0.1:40123"}
    assert DspModule.param_errors(shipped) == []
    assert load_dsp_params(shipped).port == "socket://127.0.0.1:40123"
    assert load_dsp_params({}) == DspParams(port="")


def test_unknown_key_names_the_nearest_and_is_refused_by_the_module() -> None:
    [(key, why)] = DspModule.param_errors({"prot": "/dev/ttyUSB0"})
    assert key == "prot" and "did you mean port?" in why
    with pytest.raises(ParamError, match="did you mean port"):
        load_dsp_params({"prot": "/dev/ttyUSB0"})
