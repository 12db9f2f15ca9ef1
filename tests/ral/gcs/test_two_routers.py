"""``cromat gcs`` given two ``--connect`` endpoints (issue 34 item 6): two robots on two routers are both seen and
both commanded. Each robot is the lightest real thing that answers on its own router: a session holding the RAL's
liveliness token and answering GRI task queries (it records what it was sent)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import msgspec
import zenoh

from bbcs import keys
from bbcs.contracts import gri
from bbcs.session import local_client, open_session
from bbcs.testing import Processes, child_env, start_router

ROOT = Path(__file__).resolve().parents[3]


class GriAnswerer:
    """One robot's GRI, reduced to what ``gcs robots`` and ``gcs task``/``abort`` ask of it."""

    def __init__(self, port: int, robot: str) -> None:
        self.robot = robot
        self.requests: list[msgspec.Struct] = []
        self.session = open_session(local_client(port))
        self.token = self.session.liveliness().declare_token(keys.alive_key(robot, "ral"))
        self.queryable = self.session.declare_queryable(gri.task_key(robot), self._answer)

    def _answer(self, query: zenoh.Query) -> None:
        request = gri.decode_request(query.payload.to_bytes() if query.payload is not None else b"")
        self.requests.append(request)
        query.reply(query.key_expr, gri.encode(gri.TaskReply(accepted=True, reason="", task_id=7,
                                                             task_type=self.robot)))

    def close(self) -> None:
        self.queryable.undeclare()
        self.token.undeclare()
        self.session.close()


def gcs(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "cromat", "gcs", *args], cwd=str(ROOT), env=child_env(),
                          capture_output=True, text=True, timeout=60)


def test_gcs_sees_and_commands_robots_on_two_routers() -> None:
    procs = Processes()
    robots: list[GriAnswerer] = []
    try:
        ports = [start_router(procs), start_router(procs)]
        robots = [GriAnswerer(ports[0], "ra"), GriAnswerer(ports[1], "rb")]
        both = ["--connect", f"tcp/127.0.0.1:{ports[0]}", "--connect", f"tcp/127.0.0.1:{ports[1]}",
                "--timeout", "3"]
        listed = gcs(*both, "robots")
        assert listed.returncode == 0, listed.stderr
        assert listed.stdout.split() == ["ra", "rb"]
        for robot in robots:
            sent = gcs(*both, "abort", robot.robot)
            assert sent.returncode == 0, sent.stderr
            assert [type(r) for r in robot.requests] == [gri.Abort], robot.robot
        # the control: one endpoint reaches one router's robot only
        one = gcs("--connect", f"tcp/127.0.0.1:{ports[1]}", "--timeout", "3", "robots")
        assert one.returncode == 0 and one.stdout.split() == ["rb"], one.stderr
    finally:
        for robot in robots:
            robot.close()
        procs.stop_all()
