"""The tools' connection options (issue 34 item 6): two ``--connect`` endpoints reach both routers, and
``CROMAT_GCS_CONNECT`` is the default endpoint, as for ``cromat gcs``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pytest

from bbcs.contracts.pan_tilt import DatosPT
from bbcs.session import local_client, open_session
from bbcs.slots import Direction, Kind, Publisher, Safety, SlotSpec
from bbcs.testing import Processes, start_router
from cromat.tools.connection import add_connection_options, config_from

sys.path.insert(0, str(Path(__file__).resolve().parent))
from uav_sim import ROOT  # noqa: E402


def parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_connection_options(p)
    return p.parse_args(argv)


def test_endpoints_from_the_options_or_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CROMAT_GCS_CONNECT", "tcp/127.0.0.1:1001, tcp/127.0.0.1:1002")
    both = config_from(parse([]))
    assert both.connect == ["tcp/127.0.0.1:1001", "tcp/127.0.0.1:1002"]
    assert both.mode == "peer" and both.listen == [] and not both.multicast_scouting
    one = config_from(parse(["--connect", "tcp/127.0.0.1:1003"]))  # the option replaces the environment
    assert one.connect == ["tcp/127.0.0.1:1003"] and one.mode == "client"
    monkeypatch.delenv("CROMAT_GCS_CONNECT")
    assert config_from(parse([])).connect == ["tcp/127.0.0.1:7447"]


def cromat_env(*args: str, env: dict[str, str]):
    import subprocess

    from bbcs.testing import child_env

    return subprocess.run([sys.executable, "-m", "cromat", *args], cwd=str(ROOT), env=child_env(**env),
                          capture_output=True, text=True, timeout=60)


def test_two_routers_are_both_reached_and_the_environment_names_the_router() -> None:
    procs = Processes()
    sessions, pubs = [], []
    try:
        ports = [start_router(procs), start_router(procs)]
        spec = SlotSpec("pt_datos", DatosPT, Direction.OUT, Kind.STATE, Safety.SAFE)
        for port, robot, pan in ((ports[0], "ra", 1.0), (ports[1], "rb", 2.0)):
            session = open_session(local_client(port))
            sessions.append(session)
            pub = Publisher(session, f"cromat/{robot}/ral/pt_datos", spec)
            pubs.append(pub)
            pub.publish(DatosPT(ref_pan=pan))  # a safe state: kept by its publisher for the tools joining later
        eps = [f"tcp/127.0.0.1:{p}" for p in ports]
        both = cromat_env("bus", "--connect", eps[0], "--connect", eps[1], "--timeout", "2", "echo",
                          "*/ral/pt_datos", "--json", "--count", "2", "--duration", "15", env={})
        assert both.returncode == 0, both.stderr
        got = {json.loads(line)["key"]: json.loads(line)["data"]["ref_pan"] for line in both.stdout.splitlines()}
        assert got == {"cromat/ra/ral/pt_datos": 1.0, "cromat/rb/ral/pt_datos": 2.0}
        env = cromat_env("bus", "--timeout", "2", "echo", "*/ral/pt_datos", "--json", "--count", "1",
                         "--duration", "15", env={"CROMAT_GCS_CONNECT": eps[1]})
        assert env.returncode == 0, env.stderr
        assert json.loads(env.stdout)["key"] == "cromat/rb/ral/pt_datos"
    finally:
        for pub in pubs:
            pub.close()
        for session in sessions:
            session.close()
        procs.stop_all()
