"""Two robots with lidars on one machine: the lidar manifest launched twice at once, each logger on its own
simulators at ports chosen at launch (the manifest's ``{port:ldmrs}``), never the scanner's fixed 12002."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

from modules.lidar_logger.config import read_config_file
from modules.lidar_logger.textlog import read_text_log

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "tests" / "module_manager"))
from launch_support import Launch  # noqa: E402


def robot_manifest(tmp_path: Path, robot: str) -> Path:
    """bbcs_conf/uav1_lidar_sim.toml renamed to ``robot``, logging into ``tmp_path/robot``."""
    text = (ROOT / "bbcs_conf" / "uav1_lidar_sim.toml").read_text()
    text = text.replace('name = "uav1"', f'name = "{robot}"')
    text = text.replace('conf = "uav1.conf"', f'conf = "{ROOT / "bbcs_conf" / "uav1.conf"}"')
    text = text.replace('params = { ldmrs_host', f'params = {{ out_dir = "{tmp_path / robot}", ldmrs_host')
    path = tmp_path / f"{robot}_lidar_sim.toml"
    path.write_text(text)
    (tmp_path / robot).mkdir()
    return path


@pytest.mark.timeout(180)
def test_two_lidar_robots_log_at_once_on_their_own_ports(tmp_path) -> None:
    launches = [Launch(robot_manifest(tmp_path, robot), tmp_path / f"{robot}_logs")
                for robot in ("uav1", "uav2")]
    try:
        for robot in ("uav1", "uav2"):  # each run folder fills with scans from its own scanner
            _wait_for_scans(tmp_path / robot, 20)
    finally:
        codes = [launch.stop() for launch in launches]
        for launch in launches:
            launch.cleanup()
    assert codes == [0, 0]
    ports = []
    for robot in ("uav1", "uav2"):
        run = next((tmp_path / robot).glob("Scan_*"))
        cfg = read_config_file(next(run.glob("ConfigFile_*")))
        assert cfg["end_reason"] == "signal"
        ports.append(int(cfg["ldmrs_port"]))
        assert cfg["mtig_port"].startswith(f"/tmp/cromat-{robot}-mtig-")
        log = read_text_log(next(p for p in run.glob("LogFile_*") if not p.name.endswith(".bin")))
        assert log.n_scans >= 20 and log.truncated_scans == 0
    assert len(set(ports)) == 2 and 12002 not in ports


def _wait_for_scans(folder: Path, n: int, timeout_s: float = 90.0) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        for text in folder.glob("Scan_*/LogFile_*"):
            if not text.name.endswith(".bin") and text.read_bytes().count(b"\nScan ") + 1 >= n:
                return
        time.sleep(0.2)  # polling files, with the deadline above
    raise AssertionError(f"{folder}: fewer than {n} scans logged within {timeout_s:g} s")
