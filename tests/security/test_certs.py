"""``cromat certs`` keeps the CA key (and ground-station keys) off the robot (issue 12 item 4)."""

from __future__ import annotations

import subprocess
from pathlib import Path

from cromat import certs


def _verify(ca: Path, pem: Path) -> bool:
    return subprocess.run(["openssl", "verify", "-CAfile", str(ca), str(pem)], capture_output=True).returncode == 0


def test_operator_steps_leave_only_certificates_and_own_keys_on_the_robot(tmp_path: Path) -> None:
    ca, robot, ground = tmp_path / "operator-ca", tmp_path / "robot", tmp_path / "ground"
    assert certs.main(["--init-ca", "--ca", str(ca)]) == 0
    assert {p.name for p in ca.iterdir()} == {"ca.key", "ca.pem"} and ca.stat().st_mode & 0o077 == 0
    assert certs.main([str(robot), "--ca", str(ca), "--ground", str(ground), "--gcs", "gcs",
                       "--modules", "dsp,pan_tilt"]) == 0
    assert {p.name for p in robot.iterdir()} == {
        "ca.pem", *(f"{n}.{e}" for n in ("router", "ral", "manager", "dsp", "pan_tilt") for e in ("pem", "key"))}
    assert {p.name for p in ground.iterdir()} == {"ca.pem", "gcs.pem", "gcs.key"}
    assert all(p.stat().st_mode & 0o077 == 0 for p in robot.glob("*.key"))
    assert all(_verify(ca / "ca.pem", pem) for pem in [*robot.glob("*.pem"), ground / "gcs.pem"])
    # a new module later: same CA, still nothing of the CA's on the robot
    assert certs.main([str(robot), "--ca", str(ca), "--ground", str(ground), "--module", "vision", "--no-local"]) == 0
    assert (robot / "vision.pem").is_file() and not (robot / "ca.key").exists()
    assert _verify(ca / "ca.pem", robot / "vision.pem")


def test_a_ca_key_in_the_robot_folder_is_refused(tmp_path: Path, capsys) -> None:
    robot = tmp_path / "robot"
    robot.mkdir()
    (robot / "ca.key").write_text("old layout")
    assert certs.main([str(robot), "--ca", str(tmp_path / "ca")]) == 2
    assert "a CA key in the robot's folder" in capsys.readouterr().err
    assert not (robot / "router.pem").exists()  # nothing half-made


def test_the_ground_folder_cannot_be_the_robot_folder(tmp_path: Path, capsys) -> None:
    robot = tmp_path / "robot"
    assert certs.main([str(robot), "--ground", str(robot)]) == 2
    assert "must not be the robot folder" in capsys.readouterr().err
