"""bbcs_conf/uav1.conf → DspConfig, and every mistake reported with file and line."""

from __future__ import annotations

from pathlib import Path

import pytest

from bbcs.conf import ConfError, load_conf, parse_conf
from bbcs.contracts import dsp as p
from modules.dsp.config import dsp_config_from, load_dsp_config
from modules.dsp.link import startup_commands

ROOT = Path(__file__).resolve().parents[3]
UAV1 = ROOT / "bbcs_conf" / "uav1.conf"

MINIMAL = """\
DSP_PORT: /dev/ttyUSB0
HELICOPTER_TYPE: 2
TELEMETRY: [POSITION STATUS]
MAX_SPEED: 5
PID: PITCH
{
    Kp=1 Ki=2 Kd=3
    valor_int=4 max_awu=5 min_awu=4
    referencia=3 offset=2 sat_encima=9 sat_deb=8
}
"""


def test_uav1_conf_is_complete() -> None:
    cfg = load_dsp_config(UAV1)
    assert cfg.baudrate == 921_600
    assert cfg.heli_type == p.HeliType.H3_CCPM_120
    assert cfg.telemetry_mask == p.TELEMETRY_ALL
    assert cfg.telemetry_period_ms == 50
    assert cfg.max_speed == 8.0
    assert [g.axis for g in cfg.pid_groups] == list(p.Axis)  # every controlled axis, in file order
    for group in cfg.pid_groups:
        p.check(group)
    assert cfg.source == str(UAV1)
    doc = load_conf(UAV1)
    assert doc.group("BUS", "session").get("connect") == ["tcp/127.0.0.1:7447"]


def test_port_override_for_simulation() -> None:
    assert load_dsp_config(UAV1, port="/dev/pts/9").port == "/dev/pts/9"


def test_seed_pid_example_maps_key_for_key() -> None:
    cfg = dsp_config_from(parse_conf(MINIMAL, "m.conf"))
    assert cfg.pid_groups == (p.SetPid(axis=p.Axis.PITCH, kp=1, ki=2, kd=3, integral=4, awu_max=5, awu_min=4,
                                       reference=3, offset=2, sat_high=9, sat_low=8),)
    assert cfg.telemetry_mask == p.TelemetryField.POSITION | p.TelemetryField.STATUS
    assert cfg.baudrate == 921_600 and cfg.ack_timeout_s == 0.25 and cfg.retries == 3


def test_startup_commands_follow_spec_order() -> None:
    cfg = load_dsp_config(UAV1)
    names = [type(c).__name__ for c in startup_commands(cfg)]
    assert names == ["SetSpeed", "SetTelemetryMask", "SetStateTransmission", "ClearError", "SetTracking",
                     "InvalidatePath", "SetHelicopterType"] + ["SetPid"] * 9
    first = startup_commands(cfg)
    assert first[0] == p.SetSpeed(speed=0.0)
    assert first[2] == p.SetStateTransmission(enable=True, period_ms=50)
    assert first[4] == p.SetTracking(enable=False)


@pytest.mark.parametrize(("text", "line", "match"), [
    (MINIMAL.replace("HELICOPTER_TYPE: 2", "HELICOPTER_TYPE: H9"), 2, "unknown helicopter type 'H9'"),
    (MINIMAL.replace("[POSITION STATUS]", "[POSITION ALTITUDE]"), 3, "unknown telemetry field 'ALTITUDE'"),
    (MINIMAL.replace("MAX_SPEED: 5", "MAX_SPEED: 50"), 4, "MAX_SPEED"),
    (MINIMAL.replace("MAX_SPEED: 5", "MAX_SPEED: fast"), 4, "MAX_SPEED"),
    (MINIMAL.replace("PID: PITCH", "PID: BANANA"), 5, "unknown controlled axis 'BANANA'"),
    (MINIMAL.replace("min_awu=4", "min_awu=6"), 5, "awu_min=6.0 > awu_max=5.0"),
    (MINIMAL.replace("Kd=3", "Kd=x"), 7, "'Kd'"),
    (MINIMAL.replace("Kd=3", "Kd=3 Kf=1"), 7, "unknown key 'Kf'"),
    (MINIMAL.replace("    Kp=1 Ki=2 Kd=3\n", "    Kp=1 Ki=2\n"), 5, "missing required key 'Kd'"),
    (MINIMAL.replace("TELEMETRY: [POSITION STATUS]", "TELEMETRY: POSITION"), 3, "list"),
])
def test_mistakes_name_file_and_line(text: str, line: int, match: str) -> None:
    with pytest.raises(ConfError, match=match) as info:
        dsp_config_from(parse_conf(text, "uav.conf"))
    assert info.value.path == "uav.conf"
    assert info.value.line == line
    assert str(info.value).startswith(f"uav.conf:{line}")


def test_missing_port_is_a_conf_error() -> None:
    with pytest.raises(ConfError, match="missing required key 'DSP_PORT'"):
        dsp_config_from(parse_conf(MINIMAL.replace("DSP_PORT: /dev/ttyUSB0\n", ""), "uav.conf"))


def test_missing_file_is_a_conf_error(tmp_path: Path) -> None:
    with pytest.raises(ConfError, match="cannot read"):
        load_dsp_config(tmp_path / "nope.conf")
