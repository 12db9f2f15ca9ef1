"""``[bus] peers`` in a manifest: tcp/ peers are taken and expanded into the router's ``--connect``; anything else
is refused by the manifest check naming file, key and line, before anything starts."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from module_manager.manager import Manager
from module_manager.manifest import ManifestError, load_manifest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_fleet_mesh import fleet_manifest  # noqa: E402


def test_tcp_peers_are_accepted(tmp_path) -> None:
    manifest, _ = fleet_manifest(tmp_path, "uav_p", [41001, 41002])
    m = load_manifest(manifest)
    assert m.raw.bus.peers == ["tcp/127.0.0.1:41001", "tcp/127.0.0.1:41002"]
    assert Manager(m, out=lambda _line: None).m.raw.bus.peers == m.raw.bus.peers


def test_a_tls_peer_without_bus_tls_is_refused_naming_the_key(tmp_path) -> None:
    manifest, _ = fleet_manifest(tmp_path, "uav_p", [41001])
    manifest.write_text(manifest.read_text().replace('"tcp/127.0.0.1:41001"', '"tls/127.0.0.1:41001"'))
    refusal = r"bus\.peers\.0: 'tls/127\.0\.0\.1:41001': without \[bus\.tls\] the fleet mesh"
    with pytest.raises(ManifestError, match=refusal) as err:
        load_manifest(manifest)
    assert str(manifest.name) in str(err.value)
