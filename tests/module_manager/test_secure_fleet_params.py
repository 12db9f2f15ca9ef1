"""module_manager/secure.py ``ral_fleet_params``: on a secured robot the RAL (and only it) is told the fleet CA and
the ground-station identities whose signed fleet tasks it adopts (bbcs/signing.py); an unsecured robot's RAL is
told nothing, so it adopts any task as before."""

from __future__ import annotations

from pathlib import Path

from module_manager import secure
from module_manager.manifest import load_manifest

ROOT = Path(__file__).resolve().parents[2]


def test_the_secured_ral_gets_the_fleet_ca_and_the_manifest_s_ground_stations(tmp_path: Path) -> None:
    text = (ROOT / "bbcs_conf" / "uav1_secure.toml").read_text()
    text = text.replace('conf = "uav1.conf"', f'conf = "{ROOT / "bbcs_conf" / "uav1.conf"}"')
    text = text.replace('pki = "pki"', f'pki = "{tmp_path / "pki"}"')
    old = 'gcs = ["gcs"]'
    assert text.count(old) == 1
    text = text.replace(old, 'gcs = ["gcs", "gcs_backup"]')
    path = tmp_path / "m.toml"
    path.write_text(text)
    m = load_manifest(path, check_pki=False)
    assert secure.ral_fleet_params(m, "ral") == {"fleet_ca": str(tmp_path / "pki" / "ca.pem"),
                                                 "fleet_signers": "gcs,gcs_backup",
                                                 "fleet_crl": str(tmp_path / "pki" / "crl.pem")}
    assert secure.ral_fleet_params(m, "vision") == {}


def test_an_unsecured_robot_s_ral_gets_nothing() -> None:
    m = load_manifest(ROOT / "bbcs_conf" / "uav1_sim.toml")
    assert secure.ral_fleet_params(m, "ral") == {}
