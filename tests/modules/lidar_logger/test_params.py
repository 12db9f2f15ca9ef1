"""The lidar logger's manifest params: the hook ``cromat launch --check`` calls and the module's own load agree."""

from __future__ import annotations

import pytest

from bbcs.params import ParamError
from modules.lidar_logger.config import load_lidar_params
from modules.lidar_logger.module import LidarLoggerModule

SHIPPED = {"ldmrs_host": "127.0.0.1", "ldmrs_port": "40321", "mtig_port": "/tmp/cromat-uav1-mtig-40321"}


def test_shipped_params_are_accepted_and_typed() -> None:
    assert LidarLoggerModule.param_errors(SHIPPED) == []
    assert load_lidar_params(SHIPPED)["ldmrs_port"] == 40321
    loaded = load_lidar_params({"mounting": "0,90,0,0.1,0,-0.15", "binary_log": "true", "vehicle": "CB5000"})
    assert loaded == {"mounting": (0.0, 90.0, 0.0, 0.1, 0.0, -0.15), "binary_log": True, "vehicle": "CB5000"}


def test_unknown_key_names_the_nearest_and_bad_values_are_refused() -> None:
    errors = dict(LidarLoggerModule.param_errors({"ldmrs_prot": "1", "ldmrs_port": "70000", "vehicle": "Cessna",
                                                  "mounting": "1,2", "binary_log": "maybe"}))
    assert "did you mean ldmrs_port?" in errors["ldmrs_prot"]
    assert "bad value '70000'" in errors["ldmrs_port"] and "<= 65535" in errors["ldmrs_port"]
    assert "unknown vehicle 'Cessna'" in errors["vehicle"]
    assert "length 6" in errors["mounting"] and "bad value 'maybe'" in errors["binary_log"]
    with pytest.raises(ParamError, match="ldmrs_prot: unknown lidar_logger parameter"):
        load_lidar_params({"ldmrs_prot": "1"})
