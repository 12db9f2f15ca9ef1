"""The monitor process's configuration: its limits from the robot .conf, its params refused with a reason."""

from __future__ import annotations

from pathlib import Path

import pytest

from bbcs.conf import ConfError
from bbcs.context import ModuleContext
from bbcs.params import ParamError
from modules.safety_monitor.module import SafetyMonitorModule, load_config, truth_port, uquad_truth_source

ROOT = Path(__file__).resolve().parents[3]


def context(conf: str | None = None, **params: str) -> ModuleContext:
    return ModuleContext(robot="uav1", module="safety_monitor", conf=conf, params=params)


def test_limits_come_from_the_robot_conf() -> None:
    cfg = load_config(context(conf=str(ROOT / "bbcs_conf" / "uav1.conf"), goal_tolerance_m="12"))
    assert cfg.geofence == (37.4117, -6.0025, 3000.0) and cfg.min_clearance_m == 5.0
    assert cfg.goal_tolerance_m == 12.0 and cfg.monitor_name == "safety_monitor"


def test_a_bad_conf_or_param_is_refused_naming_it(tmp_path: Path) -> None:
    bad = tmp_path / "r.conf"
    bad.write_text("ROBOT: r\nGEOFENCE: [1, 2]\n")
    with pytest.raises(ConfError, match=r"r.conf.*2|GEOFENCE"):
        load_config(context(conf=str(bad)))
    with pytest.raises(ConfError, match="abort_latency_s"):
        load_config(context(abort_latency_s="soon"))
    with pytest.raises(ConfError, match="truth_udp: bad value '10.0.0.1:9000'"):
        truth_port(context(truth_udp="10.0.0.1:9000"))
    assert truth_port(context(truth_udp="127.0.0.1:9000")) == 9000 and truth_port(context()) is None
    assert truth_port(context(truth_udp="9001")) == 9001


def test_param_hook_names_the_nearest_key_and_agrees_with_the_load() -> None:
    assert SafetyMonitorModule.param_errors({"truth_udp": "9000", "goal_tolerance_m": "12"}) == []
    errors = dict(SafetyMonitorModule.param_errors({"goal_tolerance": "12", "abort_latency_s": "-1"}))
    assert "did you mean goal_tolerance_m?" in errors["goal_tolerance"]
    assert "bad value '-1'" in errors["abort_latency_s"]
    with pytest.raises(ParamError, match="goal_tolerance: unknown safety_monitor parameter"):
        load_config(context(goal_tolerance="12"))


def test_a_uquad_monitor_reads_its_simulators_truth_stream_from_home_and_judges_no_dsp() -> None:
    conf = str(ROOT / "bbcs_conf" / "uquad1.conf")
    cfg = load_config(context(conf=conf, vehicle="uquad", truth_tcp="127.0.0.1:9100"))
    assert (cfg.dsp_commands, cfg.gri_airborne_is_motors, cfg.min_clearance_m, cfg.geofence) == (False, True, 1.0,
                                                                                                  None)
    assert uquad_truth_source(context(conf=conf, truth_tcp="127.0.0.1:9100")) == (9100, (-34.918, -56.166, 30.0))
    assert uquad_truth_source(context(conf=conf)) is None
    uav = load_config(context(conf=str(ROOT / "bbcs_conf" / "uav1.conf")))
    assert (uav.dsp_commands, uav.gri_airborne_is_motors) == (True, False)  # the default: the UAV, as before
    with pytest.raises(ParamError, match="HOME_LAT"):  # the UAV's .conf has no home: the truth's origin unknown
        uquad_truth_source(context(conf=str(ROOT / "bbcs_conf" / "uav1.conf"), truth_tcp="9100"))
    with pytest.raises(ParamError, match="vehicle"):
        load_config(context(vehicle="helicopter"))
