"""``cromat gcs`` against a real router: clear errors, and the commands driving a RAL (stand-in manager)."""

from __future__ import annotations

import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from bbcs.context import ModuleContext
from bbcs.session import local_client, open_session
from bbcs.testing import free_port, wait_until
from ral.gcs import cli
from ral.gcs.api import Gcs
from ral.process import Ral

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from standin import ROBOT, StandIn  # noqa: E402


@pytest.fixture
def robot(router: int) -> Iterator[int]:
    session = open_session(local_client(router))
    manager = StandIn(session)
    manager.start()
    ral = Ral(ModuleContext(robot=ROBOT, module="ral", bus=local_client(router)))
    thread = threading.Thread(target=ral.run, daemon=True)
    thread.start()
    try:
        with Gcs(local_client(router)) as gcs:
            wait_until(lambda: gcs.robots() == [ROBOT], 30, "RAL alive")
            wait_until(lambda: bool(gcs.state(ROBOT).available), 30, "task list known")
        yield router
    finally:
        ral.request_stop()
        thread.join(10)
        manager.close()
        session.close()


def test_unreachable_router_is_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    port = free_port()
    code = cli.main(["--connect", f"tcp/127.0.0.1:{port}", "--timeout", "1", "robots"])
    assert code == 3
    assert f"cannot reach the robot router (tcp/127.0.0.1:{port})" in capsys.readouterr().err


def test_tls_without_ca_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["--connect", "tls/127.0.0.1:1", "robots"]) == 2
    assert "--ca" in capsys.readouterr().err


def test_no_robot_answers(router: int, capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["--connect", f"tcp/127.0.0.1:{router}", "--timeout", "1", "task", "ghost", "hold"])
    assert code == 3 and "no answer from robot 'ghost'" in capsys.readouterr().err


def test_bad_waypoint_file_is_refused_before_connecting(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "wp.csv"
    f.write_text("37.4,-6,30\n37.4,-600,30\n")
    assert cli.main(["--connect", "tcp/127.0.0.1:1", "task", ROBOT, "goto", str(f)]) == 2
    assert "wp.csv:2" in capsys.readouterr().err


def test_commands_against_a_robot(robot: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    base = ["--connect", f"tcp/127.0.0.1:{robot}"]
    assert cli.main([*base, "robots"]) == 0
    assert capsys.readouterr().out.split() == [ROBOT]
    f = tmp_path / "wp.csv"
    f.write_text("".join(f"{37.41 + i * 1e-4},-6.0,30\n" for i in range(10)))
    assert cli.main([*base, "task", ROBOT, "goto", str(f), "--speed", "3"]) == 0
    assert "accepted task" in capsys.readouterr().out
    assert cli.main([*base, "task", ROBOT, "follow_path", str(f)]) == 1
    assert "no task 'follow_path'" in capsys.readouterr().out
    assert cli.main([*base, "task", ROBOT, "pan_tilt", "10", "-95"]) == 2
    assert "bad pan_tilt task" in capsys.readouterr().err
    assert cli.main([*base, "watch", ROBOT, "--count", "2"]) == 0
    out = capsys.readouterr().out
    assert out.count(f"{ROBOT} [") == 2 and "movement:goto" in out
    assert cli.main([*base, "abort", ROBOT]) == 0
    assert "abort answered in" in capsys.readouterr().out
    assert cli.main([*base, "errors", ROBOT]) == 0
