"""``[bus] peers`` with ``[bus.tls]``: tls/ peers only on a secured robot, listed by identity (``mesh_robots``,
``hubs``), and the router config that follows from them (module_manager/secure.py)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bbcs.testing import child_env
from module_manager import secure
from module_manager.manifest import ManifestError, load_manifest

ROOT = Path(__file__).resolve().parents[2]
SECURE = ROOT / "bbcs_conf" / "uav1_secure.toml"
PLAIN = ROOT / "bbcs_conf" / "uav1_sim.toml"
LISTEN = 'listen = ["tls/127.0.0.1:7447"]'
TLS = 'ral = "ral"          # the module that is the RAL (gets the RAL\'s rights in the policy)'


def secure_with(tmp_path: Path, peers: str, tls_lines: str = "") -> Path:
    text = SECURE.read_text().replace('conf = "uav1.conf"', f'conf = "{SECURE.parent / "uav1.conf"}"')
    text = text.replace('pki = "pki"', f'pki = "{tmp_path / "pki"}"')
    for old, new in ((LISTEN, f"{LISTEN}\npeers = {peers}"), (TLS, f"{TLS}\n{tls_lines}")):
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path = tmp_path / "m.toml"
    path.write_text(text)
    return path


def test_tls_peers_with_mesh_identities_give_the_router_their_rights(tmp_path: Path) -> None:
    path = secure_with(tmp_path, '["tls/127.0.0.1:7448", "tls/10.0.0.1:7447"]',
                       'mesh_robots = ["uav2", "uav3"]\nhubs = ["hub"]')
    m = load_manifest(path, check_pki=False)
    cfg = secure.router_config(m, ["tls/127.0.0.1:7447"])
    subjects = {s["id"]: s["cert_common_names"] for s in cfg["access_control"]["subjects"]}
    assert subjects["peer-uav2"] == ["router-uav2"] and subjects["peer-uav3"] == ["router-uav3"]
    assert subjects["hub"] == ["hub"]
    tls = cfg["transport"]["link"]["tls"]
    assert tls["connect_certificate"] == str(tmp_path / "pki" / "router.pem")
    assert tls["connect_private_key"] == str(tmp_path / "pki" / "router.key")
    mesh_tls = secure.router_tls(m)
    assert mesh_tls.cert == str(tmp_path / "pki" / "router.pem") and mesh_tls.mtls


@pytest.mark.parametrize(("peers", "tls_lines", "match"), [
    ('["tcp/127.0.0.1:7448"]', 'hubs = ["hub"]', r"bus\.peers\.0: 'tcp/127.0.0.1:7448': a secured robot .*tls/ only"),
    ('["tls/127.0.0.1:7448"]', "", r"bus\.peers: a secured robot's peers must be listed by identity"),
    ('["tls/127.0.0.1:7448"]', 'mesh_robots = ["uav1"]', r"bus\.tls\.mesh_robots\.0: 'uav1' is this robot"),
    ('["tls/127.0.0.1:7448"]', 'mesh_robots = ["uav/2"]', r"bus\.tls\.mesh_robots\.0: .*robot name"),
    ('["tls/127.0.0.1:7448"]', 'mesh_robots = ["uav2", "uav2"]', r"bus\.tls\.mesh_robots: a robot is listed twice"),
    ('["tls/127.0.0.1:7448"]', 'hubs = ["gcs"]', r"bus\.tls\.hubs\.0: identity 'gcs' is a ground station's"),
    ('["tls/127.0.0.1:7448"]', 'hubs = ["vision"]', r"bus\.tls\.hubs\.0: identity 'vision' is module vision's"),
    ('["tls/127.0.0.1:7448"]', 'hubs = ["router-uav2"]', r"bus\.tls\.hubs\.0: .*list robots in bus\.tls\.mesh_robots"),
])
def test_mesh_mistakes_are_manifest_errors_naming_file_and_key(tmp_path: Path, peers: str, tls_lines: str,
                                                               match: str) -> None:
    path = secure_with(tmp_path, peers, tls_lines)
    with pytest.raises(ManifestError, match=match) as err:
        load_manifest(path, check_pki=False)
    assert str(path) in str(err.value)


def test_a_tls_peer_without_tls_is_refused(tmp_path: Path) -> None:
    text = PLAIN.read_text().replace('conf = "uav1.conf"', f'conf = "{PLAIN.parent / "uav1.conf"}"')
    listen = next(line for line in text.splitlines() if line.startswith("listen = "))
    path = tmp_path / "plain.toml"
    path.write_text(text.replace(listen, f'{listen}\npeers = ["tls/127.0.0.1:7448"]', 1))
    with pytest.raises(ManifestError, match=r"bus\.peers\.0: 'tls/127\.0\.0\.1:7448': without \[bus\.tls\]"):
        load_manifest(path)


def test_launch_check_names_file_and_key(tmp_path: Path) -> None:
    path = secure_with(tmp_path, '["tcp/127.0.0.1:7448"]', 'hubs = ["hub"]')
    proc = subprocess.run([sys.executable, "-m", "module_manager.cli", str(path), "--check"], cwd=str(ROOT),
                          env=child_env(), capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert str(path) in proc.stderr and "bus.peers.0" in proc.stderr and "tls/ only" in proc.stderr
