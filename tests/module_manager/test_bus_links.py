"""``[bus] links``: which links a manifest gets, the refused combination, and what the manager hands a module."""

from __future__ import annotations

import sys
from pathlib import Path

import msgspec
import pytest

from module_manager import bus_links
from module_manager.manager import Manager
from module_manager.manifest import MANAGER_MODULE, ManifestError, load_manifest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch_support import write_manifest  # noqa: E402


def _with_bus(extra: str):
    return lambda t: t.replace('listen = ["tcp/127.0.0.1:{port:router}"]\n',
                               'listen = ["tcp/127.0.0.1:{port:router}"]\n' + extra)


def test_default_links_follow_the_default_setting(tmp_path: Path) -> None:
    m = load_manifest(write_manifest(tmp_path))
    assert m.raw.bus.links is None and bus_links.links(m) == bus_links.DEFAULT_LINKS


def test_links_peers_makes_modules_peers_and_keeps_the_manager_a_client(tmp_path: Path) -> None:
    m = load_manifest(write_manifest(tmp_path, edit=_with_bus('links = "peers"\n')))
    assert bus_links.links(m) == "peers"
    mgr = Manager(m, listen=["tcp/127.0.0.1:17447"])
    bus = mgr.module_bus_for("sink")
    assert bus.mode == "peer" and bus.listen == ["tcp/127.0.0.1:0"] and bus.connect == ["tcp/127.0.0.1:17447"]
    assert bus.access_control is None  # no [bus.tls]: no identities to enforce (as on the router)
    assert mgr.bus_for(MANAGER_MODULE).mode == "client"
    msgspec.json.encode(bus)  # it travels to the module in its context


def test_links_router_keeps_modules_clients(tmp_path: Path) -> None:
    m = load_manifest(write_manifest(tmp_path, edit=_with_bus('links = "router"\n')))
    assert bus_links.links(m) == "router"
    assert Manager(m, listen=["tcp/127.0.0.1:17447"]).module_bus_for("sink").mode == "client"


def test_hand_written_router_config_defaults_to_router_links(tmp_path: Path) -> None:
    (tmp_path / "router.json5").write_text("{}\n")
    m = load_manifest(write_manifest(tmp_path, edit=_with_bus('zenoh_config = "router.json5"\n')))
    assert bus_links.links(m) == "router"


def test_peers_with_a_hand_written_router_config_is_a_manifest_error(tmp_path: Path) -> None:
    (tmp_path / "router.json5").write_text("{}\n")
    path = write_manifest(tmp_path, edit=_with_bus('zenoh_config = "router.json5"\nlinks = "peers"\n'))
    with pytest.raises(ManifestError) as err:
        load_manifest(path)
    assert err.value.key == "bus.links" and "zenoh_config" in str(err.value)
    assert str(path) in str(err.value)


def test_unknown_links_value_is_a_manifest_error(tmp_path: Path) -> None:
    with pytest.raises(ManifestError) as err:
        load_manifest(write_manifest(tmp_path, edit=_with_bus('links = "mesh"\n')))
    assert "bus.links" in str(err.value)
