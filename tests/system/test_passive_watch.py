"""Issue 30 case 6 on the shipped ``uav1_sim.toml``: a ``cromat gcs watch uav1 --count 1`` peek makes no link, so
15 s after it (the manifest's failsafe_timeout_s is 10 s) nothing has reached the DSP and the GRI shows no
failsafe. The control case: ``cromat gcs link uav1`` held for a moment does arm it, and the failsafe then runs
(the same check would have failed before the fix, when watch held a link)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from bbcs.testing import child_env

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_gcs_mission import ROBOT, SimRobot, connect, launch_robot  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "module_manager"))
from launch_support import ROOT  # noqa: E402


def gcs_cli(port: int, *argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ral.gcs.cli", "--connect", f"tcp/127.0.0.1:{port}", *argv],
                          cwd=str(ROOT), env=child_env(), capture_output=True, text=True, timeout=60)


@pytest.mark.timeout(240)
def test_a_watch_peek_never_arms_the_failsafe_a_link_does(tmp_path: Path) -> None:
    la, record = launch_robot(tmp_path)
    try:
        robot = SimRobot(la, connect(la.port, "observer", link=False), record)
        try:
            robot.wait_state(lambda s: s.position is not None and bool(s.available), 30, "the robot's telemetry")
            time.sleep(2.0)  # the DSP's start-up sequence is in the record
            sent = len(robot.commands())
            peek = gcs_cli(la.port, "watch", ROBOT, "--count", "1")
            assert peek.returncode == 0 and f"{ROBOT} [uav]" in peek.stdout, peek.stdout + peek.stderr
            time.sleep(15.0)
            assert robot.commands()[sent:] == [], "the DSP got commands after a watch"
            assert robot.state.link == "no_gcs" and robot.state.tasks == []
            assert not [e for e in robot.events if e.kind in ("link_up", "link_lost", "failsafe")], robot.events

            # control: an explicit link for a moment arms it; 10 s after it went, the failsafe runs
            held = gcs_cli(la.port, "--name", "pilot", "link", ROBOT, "--seconds", "2")
            assert held.returncode == 0 and "holding a GCS link" in held.stdout, held.stdout + held.stderr
            robot.wait_event(lambda e: e.kind == "link_up" and "pilot" in e.detail, 10, "link_up from the link")
            fired = robot.wait_event(lambda e: e.kind == "failsafe", 25, "the failsafe after the link went")
            assert "hold" in fired.detail
            robot.wait_state(lambda s: any(t.origin == "failsafe" for t in s.tasks) or s.link == "failsafe", 10,
                             "the failsafe in the GRI state")
        finally:
            robot.gcs.close()
    finally:
        la.stop()
        la.cleanup()
