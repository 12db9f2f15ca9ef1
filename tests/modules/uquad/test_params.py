"""The uQuad modules' manifest params: the hooks ``cromat launch --check`` calls and the modules' own loads agree."""

from __future__ import annotations

import pytest

from bbcs.params import ParamError
from modules.uquad.logger import ControlLogger, StateLogger
from modules.uquad.module import UquadModule
from modules.uquad.params import load_logger_params, load_uquad_params

SHIPPED = {"imu": "tcp://127.0.0.1:4100", "gps": "tcp://127.0.0.1:4101", "motor": "tcp://127.0.0.1:4102",
           "controller": "hover"}


def test_shipped_flight_params_are_accepted_and_loaded() -> None:
    assert UquadModule.param_errors(SHIPPED) == []
    p = load_uquad_params({**SHIPPED, "nice": "-5", "clock": "imu"})
    assert (p.imu, p.motor, p.controller, p.nice, p.clock) == ("tcp://127.0.0.1:4100", "tcp://127.0.0.1:4102",
                                                               "hover", -5, "imu")


def test_flight_unknown_key_names_the_nearest_and_bad_values_are_refused() -> None:
    errors = dict(UquadModule.param_errors({"moter": "sim", "nice": "30", "clock": "gps", "controller": "pid"}))
    assert "did you mean motor?" in errors["moter"]
    assert "bad value '30'" in errors["nice"] and "<= 19" in errors["nice"]
    assert "bad value 'gps'" in errors["clock"] and "(one of: imu, wall)" in errors["clock"]
    assert "bad value 'pid'" in errors["controller"] and "(one of: hover, setpoint)" in errors["controller"]
    with pytest.raises(ParamError, match="moter: unknown uquad parameter"):
        load_uquad_params({"moter": "sim"})


def test_logger_params_checked_against_the_class() -> None:
    assert StateLogger.param_errors({"kind": "state"}) == [] and ControlLogger.param_errors({"dir": "/tmp/x"}) == []
    [(key, why)] = StateLogger.param_errors({"knd": "state"})
    assert key == "knd" and "did you mean kind?" in why
    [(key, why)] = StateLogger.param_errors({"kind": "control"})
    assert key == "kind" and "logs 'state'" in why
    with pytest.raises(ParamError, match="kind: bad value 'control'"):
        load_logger_params({"kind": "control"}, "state")
