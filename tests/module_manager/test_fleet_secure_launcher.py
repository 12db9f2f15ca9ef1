"""``cromat fleet`` of a secured fleet (module_manager/fleet.py): each robot manifest gets its pki folder in the run
dir and the hub in ``[bus.tls] hubs``, its ``tls/`` peer the hub; ``cromat certs`` issues every identity from one
fleet CA into the run dir (robot folders without a CA key, the ground station's pair apart, the hub's pair and
policy); an inconsistent secured fleet manifest is refused naming the file and key, before anything is written."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from module_manager.fleet import FleetError, load_fleet, main, robot_manifest
from module_manager.manifest import load_manifest

ROOT = Path(__file__).resolve().parents[2]
FLEET = ROOT / "bbcs_conf" / "fleet2_secure_sim.toml"
MODULES = {"dsp", "telemetry", "pan_tilt", "path_follower", "trajectory", "ral"}  # uav1_secure.toml less vision


def test_the_committed_secured_fleet_gives_robots_linked_to_the_hub_over_tls(tmp_path: Path) -> None:
    spec = load_fleet(FLEET)
    assert spec.secure and spec.hub == "hub" and spec.gcs == ("gcs",) and spec.robots == 2
    for n in (1, 2):
        name = f"uav{n:02d}"
        m = load_manifest(robot_manifest(spec, n, tmp_path, ["tls/127.0.0.1:41000"]), check_pki=False)
        tls = m.raw.bus.tls
        assert m.robot == name and m.raw.bus.peers == ["tls/127.0.0.1:41000"]
        assert tls is not None and tls.hubs == ["hub"] and tls.mesh_robots == [] and tls.gcs == ["gcs"]
        assert m.pki == tmp_path / name / "pki" and set(m.modules) == MODULES


def _subject(pem: Path) -> str:
    out = subprocess.run(["openssl", "x509", "-in", str(pem), "-noout", "-subject"], capture_output=True, text=True,
                         check=True).stdout
    return out.strip().replace(" ", "").removeprefix("subject=")


def test_check_issues_every_identity_from_one_fleet_ca(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run"
    assert main([str(FLEET), "--run-dir", str(run), "--check"]) == 0
    out = capsys.readouterr().out
    ground = run / "ground"
    assert f"--ca {ground / 'ca.pem'} --cert {ground / 'gcs.pem'} --key {ground / 'gcs.key'} robots" in out
    assert "cromat gcs --connect tls/127.0.0.1:" in out
    ca = (run / "ca" / "ca.pem").read_bytes()
    assert (run / "ca" / "ca.key").stat().st_mode & 0o777 == 0o600
    for name in ("uav01", "uav02"):
        pki = run / name / "pki"
        m = load_manifest(run / name / f"{name}.toml")  # the full check: every certificate file there
        assert m.pki == pki
        assert {p.stem for p in pki.glob("*.pem")} == {"ca", "router", "manager", *MODULES}
        assert {p.stem for p in pki.glob("*.key")} == {"router", "manager", *MODULES}  # no CA key, no station key
        assert all(p.stat().st_mode & 0o777 == 0o600 for p in pki.glob("*.key"))
        assert (pki / "ca.pem").read_bytes() == ca
        assert _subject(pki / "router.pem") == f"CN=router-{name}"  # its identity on the hub and the mesh
        assert _subject(pki / "ral.pem") == "CN=ral"
    assert {p.name for p in ground.iterdir()} == {"ca.pem", "gcs.pem", "gcs.key"}
    assert _subject(ground / "gcs.pem") == "CN=gcs" and (ground / "ca.pem").read_bytes() == ca
    assert {p.name for p in (run / "hub").iterdir()} == {"ca.pem", "hub.pem", "hub.key"}
    assert _subject(run / "hub" / "hub.pem") == "CN=hub"
    cfg = json.loads((run / "hub.json5").read_text().split("\n", 1)[1])
    subjects = {s["id"]: s["cert_common_names"] for s in cfg["access_control"]["subjects"]}
    assert subjects == {"gcs": ["gcs"], "robot-uav01": ["router-uav01"], "robot-uav02": ["router-uav02"]}
    assert cfg["access_control"]["default_permission"] == "deny"
    assert cfg["transport"]["link"]["tls"]["enable_mtls"] is True
    assert cfg["listen"]["endpoints"][0].startswith("tls/127.0.0.1:")


def _fleet(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "fleet.toml"
    path.write_text("[fleet]\nrobots = 2\n" + body.replace("CONF/", f"{ROOT / 'bbcs_conf'}/"))
    return path


def _secure_with(tmp_path: Path, extra: str) -> Path:
    """uav1_secure.toml in ``tmp_path`` (its .conf absolute) with ``extra`` lines under ``[bus.tls]``."""
    text = (ROOT / "bbcs_conf" / "uav1_secure.toml").read_text()
    text = text.replace('conf = "uav1.conf"', f'conf = "{ROOT / "bbcs_conf" / "uav1.conf"}"')
    path = tmp_path / "robot.toml"
    path.write_text(text.replace("[bus.tls]\n", f"[bus.tls]\n{extra}\n", 1))
    return path


@pytest.mark.parametrize("body, why", [
    ('manifest = "CONF/uav1_sim.toml"\nsecure = true\n', r"\[fleet\] secure = true but manifest .*uav1_sim\.toml "
                                                        r"has no \[bus\.tls\]"),
    ('manifest = "CONF/uav1_secure.toml"\nsecure = false\n', r"\[fleet\] secure = false but manifest .* has "
                                                             r"\[bus\.tls\]"),
    ('manifest = "CONF/uav1_secure.toml"\nsecure = "yes"\n', r"\[fleet\] secure = 'yes': true or false"),
    ('manifest = "CONF/uav1_secure.toml"\nhub = "router-x"\n', r"\[fleet\] hub = 'router-x' is a robot router's"),
    ('manifest = "CONF/uav1_secure.toml"\nhub = "uav02"\n', r"\[fleet\] hub = 'uav02' is a robot's name"),
    ('manifest = "CONF/uav1_secure.toml"\nhub = "gcs"\n', r"\[fleet\] hub = 'gcs' is a ground station's identity"),
    ('manifest = "CONF/uav1_secure.toml"\nhub = "a/b"\n', r"\[fleet\] hub: hub identity 'a/b'"),
    ('manifest = "CONF/uav1_secure.toml"\nhub = 7\n', r"\[fleet\] hub = 7: the hub router's identity"),
    ('manifest = "CONF/uav1_secure.toml"\nhub = "ral"\n', r"\[fleet\] hub = 'ral' is module ral's identity"),
    ('manifest = "CONF/uav1_secure.toml"\ndrop = ["bus.tls"]\n', r"\[fleet\] drop: 'bus\.tls': a secured fleet keeps"),
    ('manifest = "CONF/uav1_sim.toml"\nhub = "hub"\n', r"\[fleet\] hub: a hub identity is for a secured fleet"),
])
def test_an_inconsistent_secured_fleet_is_refused_naming_file_and_key(tmp_path: Path, body: str, why: str) -> None:
    path = _fleet(tmp_path, body)
    with pytest.raises(FleetError, match=why) as err:
        load_fleet(path)
    assert str(path) in str(err.value)
    assert main([str(path), "--run-dir", str(tmp_path / "run")]) == 1
    assert not (tmp_path / "run").exists()  # refused before anything was written or started


@pytest.mark.parametrize("key", ["hubs", "mesh_robots"])
def test_a_robot_manifest_with_its_own_mesh_is_refused(tmp_path: Path, key: str) -> None:
    robot = _secure_with(tmp_path, f'{key} = ["elsewhere"]')
    path = _fleet(tmp_path, f'manifest = "{robot}"\n')
    with pytest.raises(FleetError, match=rf"\[fleet\] manifest: .*robot\.toml: bus\.tls\.{key} is set") as err:
        load_fleet(path)
    assert str(path) in str(err.value)
