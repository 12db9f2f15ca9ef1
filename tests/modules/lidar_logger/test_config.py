"""The LIDAR group of a robot .conf and the vehicle lever arms of seed Table 12."""

from __future__ import annotations

import pytest

from bbcs.conf import ConfError
from modules.lidar_logger.config import load_lidar_conf, read_config_file
from modules.lidar_logger.vehicles import VEHICLES, vehicle_key

ROBOT = """\
ROBOT: uav1
LIDAR: logger {
    VEHICLE: cb5000          # the helicopter
    MTIG_PORT: /dev/ttyUSB1
    LDMRS_HOST: 192.168.0.1
    DURATION_MIN: 20
    BINARY_LOG: true
    MOUNTING: [0, 90, 0, 0.10, 0, -0.15]
}
"""


def test_lever_arms_of_table_12() -> None:
    assert VEHICLES["PILATUS_PORTER"] == (-0.45, -0.04, 0.0)
    assert VEHICLES["CB5000"] == (-0.34, 0.01, 0.26)
    assert vehicle_key("Pilatus Porter") == "PILATUS_PORTER" and vehicle_key(" cb5000 ") == "CB5000"
    with pytest.raises(ValueError, match="unknown vehicle 'Cessna'"):
        vehicle_key("Cessna")


def test_group_is_read_and_typed(tmp_path) -> None:
    path = tmp_path / "uav1.conf"
    path.write_text(ROBOT)
    conf = load_lidar_conf(path)
    assert conf.vehicle == "cb5000" and conf.lever_arm_m == (-0.34, 0.01, 0.26)
    assert conf.mtig_port == "/dev/ttyUSB1" and conf.ldmrs_port == 12002 and conf.binary_log is True
    assert conf.duration_min == 20.0 and conf.event_timeout_s == 15.0
    assert conf.mounting_struct.pitch == 90.0 and conf.mounting_struct.z == -0.15


@pytest.mark.parametrize(
    "bad, line, message",
    [
        ("    VEHICLE: cessna\n", 2, "unknown vehicle"),
        ("    VEHICLE: cb5000\n    LDMRS_PORT: 99999\n", 3, "LDMRS_PORT"),
        ("    VEHICLE: cb5000\n    EVENT_TIMEOUT: 3\n", 3, "unknown key 'EVENT_TIMEOUT'"),
        ("    VEHICLE: cb5000\n    MOUNTING: [0, 90]\n", 3, "MOUNTING"),
    ],
)
def test_errors_name_file_and_line(tmp_path, bad, line, message) -> None:
    path = tmp_path / "bad.conf"
    path.write_text("LIDAR: logger {\n" + bad + "}\n")
    with pytest.raises(ConfError, match=message) as info:
        load_lidar_conf(path)
    assert info.value.path == str(path) and info.value.line == line


def test_missing_group_or_vehicle(tmp_path) -> None:
    path = tmp_path / "none.conf"
    path.write_text("ROBOT: uav1\n")
    with pytest.raises(ConfError, match="missing group 'LIDAR: logger'"):
        load_lidar_conf(path)
    path.write_text("LIDAR: logger {\n MTIG_PORT: /dev/x\n}\n")
    with pytest.raises(ConfError, match="VEHICLE"):
        load_lidar_conf(path)


def test_run_config_file_reader(tmp_path) -> None:
    path = tmp_path / "ConfigFile_x"
    path.write_text("# comment\nmounting_pitch_deg: 90.0   # looking down\nrun: Scan_Y2010\n\n")
    assert read_config_file(path) == {"mounting_pitch_deg": "90.0", "run": "Scan_Y2010"}
