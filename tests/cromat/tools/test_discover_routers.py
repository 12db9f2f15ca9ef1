"""The bus tools' discovery given two ``--connect`` endpoints (issue 34 item 6): the modules alive behind each
router are found, as ``cromat gcs robots`` finds each router's robots (tests/ral/gcs/test_two_routers.py). Each
module is the lightest real thing: a session on its own router holding the module's liveliness token."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from bbcs import keys
from bbcs.session import local_client, open_session
from bbcs.testing import Processes, child_env, start_router
from cromat.tools.catalog import discover
from ral.gcs.api import session_config

ROOT = Path(__file__).resolve().parents[3]


def test_discovery_finds_the_modules_behind_each_router() -> None:
    procs = Processes()
    holders = []
    try:
        ports = [start_router(procs), start_router(procs)]
        for port, robot in zip(ports, ("ra", "rb"), strict=True):
            s = open_session(local_client(port))
            holders.append((s, s.liveliness().declare_token(keys.alive_key(robot, "sensor"))))
        cfg = session_config([f"tcp/127.0.0.1:{p}" for p in ports])
        session = open_session(cfg)
        try:
            cat = discover(session, "*", 2.0, cfg)
        finally:
            session.close()
        assert sorted(cat.modules) == [("ra", "sensor"), ("rb", "sensor")]
        # the command line the same way: `cromat bus graph` names both robots' modules
        graph = subprocess.run([sys.executable, "-m", "cromat", "bus", "--connect", f"tcp/127.0.0.1:{ports[0]}",
                                "--connect", f"tcp/127.0.0.1:{ports[1]}", "--timeout", "2", "graph"],
                               cwd=str(ROOT), env=child_env(), capture_output=True, text=True, timeout=60)
        assert graph.returncode == 0, graph.stderr
        assert "ra" in graph.stdout and "rb" in graph.stdout, graph.stdout
    finally:
        for s, token in holders:
            token.undeclare()
            s.close()
        procs.stop_all()
