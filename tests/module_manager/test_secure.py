"""module_manager/secure.py: the router config and client configs generated from a ``[bus.tls]`` manifest."""

from __future__ import annotations

from pathlib import Path

import pytest

from module_manager import secure
from module_manager.manifest import ManifestError, load_manifest

ROOT = Path(__file__).resolve().parents[2]
MANIFEST = ROOT / "bbcs_conf" / "uav1_secure.toml"


def manifest_with(tmp_path: Path, old: str = "", new: str = "") -> Path:
    text = MANIFEST.read_text().replace('conf = "uav1.conf"', f'conf = "{MANIFEST.parent / "uav1.conf"}"')
    text = text.replace('pki = "pki"', f'pki = "{tmp_path / "pki"}"')
    if old:
        assert text.count(old) == 1
        text = text.replace(old, new)
    path = tmp_path / "m.toml"
    path.write_text(text)
    return path


def test_identity_key_maps_the_module_subject_to_that_certificate(tmp_path: Path) -> None:
    path = manifest_with(tmp_path, 'entry = "modules.vision"', 'entry = "modules.vision"\nidentity = "cam1"')
    m = load_manifest(path, check_pki=False)
    assert secure.identities(m) == ["manager", "gcs", "dsp", "telemetry", "pan_tilt", "path_follower", "cam1",
                                    "trajectory", "ral"]
    cfg = secure.router_config(m, ["tls/127.0.0.1:7447"])
    subjects = {s["id"]: s["cert_common_names"] for s in cfg["access_control"]["subjects"]}
    assert subjects["m-vision"] == ["cam1"] and subjects["ral"] == ["ral"] and subjects["gcs"] == ["gcs"]
    assert "m-ral" not in subjects  # the RAL gets the RAL's rights, not a module's
    rules = {r["id"]: r for r in cfg["access_control"]["rules"]}
    assert "cromat/uav1/vision/*" in rules["m-vision-write"]["key_exprs"]
    tls = cfg["transport"]["link"]["tls"]
    assert tls["listen_certificate"] == str(tmp_path / "pki" / "router.pem") and tls["enable_mtls"]
    bus = secure.client_bus(m, ["tls/127.0.0.1:7447"], m.identity("vision"))
    assert bus.tls is not None and bus.tls.cert == str(tmp_path / "pki" / "cam1.pem") and bus.tls.mtls


def test_acl_false_keeps_mtls_without_a_policy(tmp_path: Path) -> None:
    m = load_manifest(manifest_with(tmp_path, "acl = true ", "acl = false"), check_pki=False)
    cfg = secure.router_config(m, ["tls/127.0.0.1:7447"])
    assert "access_control" not in cfg and cfg["transport"]["link"]["protocols"] == ["tls"]


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ('listen = ["tls/127.0.0.1:7447"]', 'listen = ["tcp/127.0.0.1:7447"]', r"bus\.listen\.0: .*tls/ only"),
        ('entry = "modules.vision"', 'entry = "modules.vision"\nidentity = "gcs"', "ground station"),
        ('entry = "modules.vision"', 'entry = "modules.vision"\nidentity = "dsp"', "module dsp"),
    ],
)
def test_tls_mistakes_are_manifest_errors(tmp_path: Path, old: str, new: str, match: str) -> None:
    with pytest.raises(ManifestError, match=match):
        load_manifest(manifest_with(tmp_path, old, new), check_pki=False)


def test_missing_pki_folder_is_named(tmp_path: Path) -> None:
    with pytest.raises(ManifestError, match=r"bus\.tls\.pki: certificate folder .*pki does not exist"):
        load_manifest(manifest_with(tmp_path))


def test_router_cn_is_read_from_the_routers_certificate(tmp_path: Path) -> None:
    from cromat import certs

    path = manifest_with(tmp_path)
    assert certs.main(["--manifest", str(path)]) == 0
    assert secure.router_cn(load_manifest(path)) == "router-uav1"


def test_an_unreadable_router_certificate_is_named(tmp_path: Path) -> None:
    (tmp_path / "router.pem").write_text("not a certificate\n")
    with pytest.raises(ValueError, match=r"router\.pem: cannot read the router's certificate"):
        secure.certificate_cn(tmp_path / "router.pem")
