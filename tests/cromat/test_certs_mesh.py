"""``cromat certs`` for the fleet mesh: a robot's router certificate is named ``router-<robot>`` (its identity on
other routers' policies) and ``--hub`` issues a hub router's pair and config, all signed by one fleet CA."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import zenoh

from cromat import certs


def _subject(pem: Path) -> str:
    return subprocess.run(["openssl", "x509", "-in", str(pem), "-noout", "-subject", "-nameopt", "RFC2253"],
                          capture_output=True, text=True, check=True).stdout.strip()


def _verify(ca: Path, pem: Path) -> bool:
    return subprocess.run(["openssl", "verify", "-CAfile", str(ca), str(pem)], capture_output=True).returncode == 0


def test_router_and_hub_certificates_share_the_fleet_ca(tmp_path: Path) -> None:
    ca = tmp_path / "ca"
    for robot in ("uav1", "uav2"):
        assert certs.main([str(tmp_path / robot), "--robot", robot, "--ca", str(ca), "--modules", "dsp",
                           "--ground", str(tmp_path / "ground")]) == 0
        assert _subject(tmp_path / robot / "router.pem") == f"subject=CN=router-{robot}"
        assert _verify(ca / "ca.pem", tmp_path / robot / "router.pem")
    assert _subject(tmp_path / "uav1" / "dsp.pem") == "subject=CN=dsp"
    assert certs.main([str(tmp_path / "any"), "--ca", str(ca), "--ground", str(tmp_path / "ground")]) == 0
    assert _subject(tmp_path / "any" / "router.pem") == "subject=CN=router"  # no robot named: as before

    hub = tmp_path / "hub"
    assert certs.main([str(hub), "--hub", "hub", "--ca", str(ca), "--router-host", "ground.local", "--robots",
                       "uav1,uav2", "--acl", str(tmp_path / "hub.json5")]) == 0
    assert {p.name for p in hub.iterdir()} == {"ca.pem", "hub.pem", "hub.key"}  # no CA key with the hub
    assert _subject(hub / "hub.pem") == "subject=CN=hub" and _verify(ca / "ca.pem", hub / "hub.pem")
    assert hub.joinpath("hub.key").stat().st_mode & 0o077 == 0
    zenoh.Config.from_file(str(tmp_path / "hub.json5"))
    text = (tmp_path / "hub.json5").read_text()
    cfg = json.loads("\n".join(line for line in text.splitlines() if not line.startswith("//")))
    subjects = {s["id"]: s["cert_common_names"] for s in cfg["access_control"]["subjects"]}
    assert subjects == {"gcs": ["gcs"], "robot-uav1": ["router-uav1"], "robot-uav2": ["router-uav2"]}
    assert cfg["transport"]["link"]["tls"]["connect_certificate"] == str((hub / "hub.pem").resolve())


def test_hub_mistakes_are_refused_and_make_nothing(tmp_path: Path, capsys) -> None:
    assert certs.main([str(tmp_path / "hub"), "--hub", "hub"]) == 2
    assert "--hub needs" in capsys.readouterr().err
    assert certs.main([str(tmp_path / "hub"), "--hub", "bad/name", "--ca", str(tmp_path / "ca")]) == 2
    assert not (tmp_path / "hub").exists()
