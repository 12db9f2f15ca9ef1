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
