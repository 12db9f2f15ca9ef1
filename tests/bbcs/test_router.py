"""``cromat router --admin-space``: the router's Zenoh admin space answers queries only when asked for."""

from __future__ import annotations

import subprocess

import pytest

from bbcs.net import free_port
from bbcs.testing import wait_port


@pytest.mark.parametrize("admin_space", [False, True])
def test_router_admin_space_only_when_enabled(processes, clients, admin_space):
    port = free_port()
    processes.start(["-m", "bbcs.router", "--listen", f"tcp/127.0.0.1:{port}",
                     *(["--admin-space"] if admin_space else [])], stdout=subprocess.DEVNULL)
    wait_port(port)
    session = clients(port)
    keys = [str(r.ok.key_expr) for r in session.get("@/*/router/**", timeout=5) if r.ok is not None]
    if admin_space:
        assert any(k.endswith("/router") for k in keys), keys
        assert any(k.endswith("/router/metrics") for k in keys), keys
    else:
        assert keys == []


def test_a_robots_router_id_comes_from_its_name_alone() -> None:
    """Same name, same Zenoh id (so the mesh refuses a second robot of it); another name, another id."""
    from bbcs.router import robot_router_zid

    a = robot_router_zid("uav1")
    assert a == robot_router_zid("uav1") and len(a) == 32 and int(a, 16) != 0
    assert robot_router_zid("uav2") != a


OPEN = ("\x1b[2m2026-11-24T11:41:16.288837Z\x1b[0m \x1b[31mERROR\x1b[0m net-0 ThreadId(03) zenoh_transport::unicast::"
        "establishment::open: Received a close message (reason {why}) in response to an OpenSyn on: "
        "TransportLinkUnicast {{ link: Link {{ src: tcp/127.0.0.1:35366, dst: tcp/127.0.0.1:54611, mtu: 65480 }} }}")
SELF = ("2026-11-24T11:41:16.288691Z  WARN acc-0 ThreadId(04) zenoh_transport::unicast::manager: ab12 Attempt to "
        "establish transport to itself at manager.rs:616.")


def test_the_meshs_refusal_of_a_same_named_router_is_said_on_both_sides() -> None:
    from bbcs.router_audit import MESH_REFUSED, parse

    for why in ("INVALID", "CONNECTION_TO_SELF"):  # through a hub / straight to the other robot's router
        got = parse(OPEN.format(why=why))
        assert got is not None and got.kind == MESH_REFUSED
        assert got.text.startswith(f"the router at tcp/127.0.0.1:54611 closed this router's link at the handshake "
                                   f"(reason {why})") and "robot names must be unique" in got.text
    got = parse(SELF)
    assert got is not None and got.kind == MESH_REFUSED and "(ab12)" in got.text
    assert parse(OPEN.format(why="GENERIC")) is None
