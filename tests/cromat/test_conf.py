"""``cromat conf check FILE``: every bad value of a robot's .conf is reported with its file:line, all at once: the
UAV's DSP keys and the RAL's limits, the uQuad's keys and groups; by default with the modules of the manifests
beside the file that name it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bbcs.testing import child_env
from cromat.conf import check_file, main

ROOT = Path(__file__).resolve().parents[2]
UAV1 = ROOT / "bbcs_conf" / "uav1.conf"


def broken(tmp_path: Path, old: str, new: str) -> tuple[Path, int]:
    """uav1.conf with ``old`` replaced by ``new``; the path and the 1-based line of the change."""
    text = UAV1.read_text()
    assert old in text
    path = tmp_path / "uav1.conf"
    path.write_text(text.replace(old, new, 1))
    line = text[: text.index(old)].count("\n") + 1
    return path, line


@pytest.mark.parametrize("old,new,says", [
    ("MAX_SPEED: 8.0", "MAX_SPEED: fast", "key 'MAX_SPEED': invalid value 'fast': expected `float`"),
    ("MAX_SPEED: 8.0", "MAX_SPEED: 500", "key 'MAX_SPEED': invalid value '500': expected `float` <= 30"),
    ("DSP_RETRIES: 3", "DSP_RETRIES: -1", "key 'DSP_RETRIES': invalid value '-1': expected `int` >= 0"),
    ("TELEMETRY_PERIOD_MS: 50", "TELEMETRY_PERIOD_MS: 5", "key 'TELEMETRY_PERIOD_MS'"),
    ("DSP_BAUD: 921600", "DSP_BAUD: fast", "key 'DSP_BAUD'"),
    ("TELEMETRY: [POSITION, ATTITUDE,", "TELEMETRY: [POSITION, ATTITUD,",
     "key 'TELEMETRY' (item 2 of the list): unknown telemetry field 'ATTITUD'"),
    ("HELICOPTER_TYPE: H3_CCPM_120", "HELICOPTER_TYPE: BLIMP", "unknown helicopter type 'BLIMP'"),
    ("PID: ROLL", "PID: WOBBLE", "unknown controlled axis 'WOBBLE'"),
    ("MAX_SPEED: 8.0", "MAX_SPED: 8.0", "missing required key 'MAX_SPEED': is 'MAX_SPED' a misspelling?"),
    ("    Kp=0.045", "    Kpp=0.045", "missing required key 'Kp' in group 'PID: ROLL': is 'Kpp' a misspelling?"),
    ("Kp=0.045", "Kp=much", "key 'Kp' in group 'PID: ROLL': invalid value 'much'"),
    ("MAX_HEIGHT: 120.0", "MAX_HEIGHT: high", "key 'MAX_HEIGHT': invalid value 'high'"),
    ("MAX_HEIGHT: 120.0", "MAX_HEIGHT: -5", "key 'MAX_HEIGHT': invalid value '-5': expected `float` > 0"),
    ("CRUISE_SPEED: 5.0", "CRUISE_SPEED: 9.0", "CRUISE_SPEED 9 is above MAX_SPEED 8"),
    ("GEOFENCE: [37.4117, -6.0025, 3000]", "GEOFENCE: [37.4117, -6.0025, 0]",
     "GEOFENCE must be [latitude, longitude, radius in m > 0]"),
    ("GEOFENCE: [37.4117, -6.0025, 3000]", "GEOFENCE: [37.4117, -6.0025]", "key 'GEOFENCE'"),
    ("VEHICLE: CB5000", "VEHICLE: ZEPPELIN", "ZEPPELIN"),
    ("LDMRS_PORT: 12002", "LDMRS_PORT: 70000", "key 'LDMRS_PORT' in group 'LIDAR: logger': invalid value '70000'"),
    ("BINARY_LOG: true", "BINARY_LOGS: true", "unknown key 'BINARY_LOGS' in group 'LIDAR: logger'"),
])
def test_each_bad_value_is_reported_at_its_line(tmp_path, old, new, says):
    path, line = broken(tmp_path, old, new)
    errors = check_file(path)
    assert len(errors) == 1, errors
    assert str(errors[0]).startswith(f"{path}:{line}:"), str(errors[0])
    assert says in str(errors[0])


def test_every_error_is_reported_in_one_run(tmp_path, capsys):
    text = UAV1.read_text().replace("MAX_SPEED: 8.0", "MAX_SPEED: fast").replace("DSP_RETRIES: 3", "DSP_RETRIES: 99")
    text = text.replace("NAV, SPEED", "NAV, SPED")
    path = tmp_path / "uav1.conf"
    path.write_text(text)
    assert main(["check", str(path)]) == 1
    err = capsys.readouterr().err
    assert "'MAX_SPEED'" in err and "'DSP_RETRIES'" in err and "'SPED'" in err
    assert "3 error(s)" in err


def test_a_syntax_error_is_reported_at_its_line(tmp_path):
    path, line = broken(tmp_path, "PID: PITCH\n{", "PID: PITCH\n{{")
    errors = check_file(path)
    assert len(errors) == 1 and str(errors[0]).startswith(f"{path}:{line + 1}:")


def test_the_shipped_conf_is_valid_through_the_cromat_command():
    out = subprocess.run([sys.executable, "-m", "cromat", "conf", "check", str(UAV1), "--manifest",
                          str(ROOT / "bbcs_conf" / "uav1_sim.toml")], cwd=ROOT, env=child_env(),
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "ok (checked by modules.dsp.module:DspModule, ral.module:Ral)" in out.stdout  # uav1_sim has no lidar


def test_the_cromat_command_exits_non_zero_on_a_bad_value(tmp_path):
    path, line = broken(tmp_path, "MAX_SPEED: 8.0", "MAX_SPEED: fast")
    out = subprocess.run([sys.executable, "-m", "cromat", "conf", "check", str(path)], cwd=ROOT, env=child_env(),
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 1
    assert f"{path}:{line}:1: key 'MAX_SPEED'" in out.stderr


UQUAD1 = ROOT / "bbcs_conf" / "uquad1.conf"
UQUAD = "modules.uquad.module:UquadModule"


def broken_uquad(tmp_path: Path, old: str, new: str) -> tuple[Path, int]:
    """uquad1.conf (and the manifest that names it, beside it) with ``old`` replaced by ``new``."""
    text = UQUAD1.read_text()
    assert old in text
    (tmp_path / "uquad1_sim.toml").write_text((ROOT / "bbcs_conf" / "uquad1_sim.toml").read_text()
                                              .replace('pythonpath = [".."]', f'pythonpath = ["{ROOT}"]'))
    path = tmp_path / "uquad1.conf"
    path.write_text(text.replace(old, new, 1))
    return path, text[: text.index(old)].count("\n") + 1


def test_the_uquad_conf_is_checked_by_the_manifest_beside_it(capsys):
    assert main(["check", str(UQUAD1)]) == 0
    out = capsys.readouterr().out
    assert f"ok (checked by {UQUAD}, ral.module:Ral)" in out, out


@pytest.mark.parametrize("old,new,says", [
    ("    q_int = [0.4 0.4 0.8 0.1]", "    q_int = [0.4 0.4 0.8]",
     "key 'q_int' in group 'LQR: weights' must have 4 values, has 3"),
    ("MOTOR_MIN: 300.0", "MOTOR_MIN: 900.0", "MOTOR_MIN must be > 0 and below MOTOR_MAX"),
    ("MOTOR_MIN: 300.0", "MOTOR_MIN: slow", "key 'MOTOR_MIN': invalid value 'slow'"),
    ("QUAD: model {", "QUAD: modle {", "missing group 'QUAD: model'"),
    ("MAX_SPEED: 4.0", "MAX_SPEED: 0", "key 'MAX_SPEED': invalid value '0': expected `float` > 0"),
])
def test_each_bad_uquad_value_is_reported(tmp_path, capsys, old, new, says):
    path, line = broken_uquad(tmp_path, old, new)
    assert main(["check", str(path)]) == 1
    err = capsys.readouterr().err
    assert says in err, err
    if "group" not in says or "must have" in says:
        assert f"{path}:{line}:" in err, err
    assert f"(checked by {UQUAD}, ral.module:Ral)" in err
    assert "DSP_PORT" not in err, "the UAV's DSP keys are not asked of a uQuad"


def test_the_uquad_module_refuses_what_the_check_reports(tmp_path):
    from bbcs.conf import ConfError
    from modules.uquad.config import load_config

    path, line = broken_uquad(tmp_path, "MOTOR_MIN: 300.0", "MOTOR_MIN: 900.0")
    with pytest.raises(ConfError) as info:
        load_config(path)
    assert str(info.value) == str(check_file(path, [UQUAD])[0])


def test_the_uav_conf_is_checked_by_every_module_of_the_manifests_beside_it(capsys):
    assert main(["check", str(UAV1)]) == 0
    out = capsys.readouterr().out
    assert ("ok (checked by modules.dsp.module:DspModule, modules.lidar_logger.module:LidarLoggerModule, "
            "ral.module:Ral)") in out, out


def test_the_lidar_logger_refuses_what_the_check_reports(tmp_path):
    from bbcs.conf import ConfError
    from modules.lidar_logger.config import load_lidar_conf

    path, _ = broken(tmp_path, "LDMRS_PORT: 12002", "LDMRS_PORT: 70000")
    with pytest.raises(ConfError) as info:
        load_lidar_conf(path)
    assert str(info.value) == str(check_file(path)[0])
