"""GCS killed mid-mission: a ground-station process holding the link is SIGKILLed while the robot flies a
path; after the configured (short) failsafe time the RAL runs its action (hold: the path follower's abort
command, the DSP's queue empties), reports it in events, and a ground station coming back sees the robot
again and is told the failsafe stays in force (the mission does not resume)."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
from pathlib import Path

from bbcs.contracts import gri
from bbcs.testing import child_env, wait_until

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_gcs_mission import ROBOT, SimRobot, connect, grid_path, launch_robot  # noqa: E402

FAILSAFE_S = 1.5
GCS_SCRIPT = """
import sys, time
from ral.gcs.api import Gcs, session_config
gcs = Gcs(session_config([sys.argv[1]]), name="field_station", link=["uav1"])
print("linked", flush=True)
while True:
    time.sleep(1)
"""


def test_gcs_killed_mid_mission_triggers_failsafe_then_gcs_back_sees_robot(tmp_path: Path) -> None:
    # heartbeats come every 0.5 s: a 1 s timeout would drop the link whenever a loaded machine delays one; the
    # killed station's link goes with its liveliness token (its socket closes), which this does not delay
    la, record = launch_robot(
        tmp_path, ral={"failsafe_timeout_s": str(FAILSAFE_S), "heartbeat_timeout_s": "3"}
    )
    observer = station = back = None
    try:
        observer = connect(la.port, "observer", link=False)  # watches and commands, holds no link
        robot = SimRobot(la, observer, record)
        station = subprocess.Popen(
            [sys.executable, "-c", GCS_SCRIPT, f"tcp/127.0.0.1:{la.port}"],
            env=child_env(),
            stdout=subprocess.PIPE,
            text=True,
        )
        assert station.stdout is not None and station.stdout.readline().strip() == "linked"
        robot.wait_event(lambda e: e.kind == "link_up" and "field_station" in e.detail, 20, "link up")
        up = robot.ensure_airborne()
        reply = observer.send(ROBOT, gri.FollowPath(waypoints=grid_path(up.position, scale=6), speed=5.0))
        assert reply.accepted, reply.reason
        robot.wait_state(lambda s: (s.waypoints_queued or 0) >= 5, 20, "mid-path")

        start = len(robot.events)
        n_cmd = len(robot.commands())
        station.send_signal(signal.SIGKILL)
        station.wait(10)
        lost = robot.wait_event(lambda e: e.kind == "link_lost", 20, "link_lost", after=start)
        fs = robot.wait_event(lambda e: e.kind == "failsafe", 20, "failsafe event", after=start)
        # in that order, and only after the configured time of loss by the RAL's own account (no wall-clock
        # threshold here: a loaded machine only makes it later)
        with robot.lock:
            after_kill = robot.events[start:]
        assert after_kill.index(lost) < after_kill.index(fs)
        waited = re.search(r"no ground station for (\d+\.\d) s", fs.detail)
        assert waited is not None and float(waited.group(1)) >= FAILSAFE_S and "hold" in fs.detail, fs.detail
        robot.wait_event(
            lambda e: e.kind == "task_accepted" and "(failsafe)" in e.detail,
            20,
            "the failsafe hold accepted",
            after=start,
        )
        # the hold is in the RAL's task list only once the manager has answered, which the queue can beat
        held = robot.wait_state(
            lambda s: s.waypoints_queued == 0 and s.link == "failsafe" and any(t.origin == "failsafe" for t in s.tasks),
            20,
            "DSP queue emptied by the failsafe",
        )
        assert [(t.kind, t.origin) for t in held.tasks] == [("hold", "failsafe")]
        assert "ABORT" in [c["name"] for c in robot.commands()[n_cmd:]]

        # a ground station comes back: it sees the robot within seconds; the failsafe stays in force
        start = len(robot.events)
        back = connect(la.port, "field_station_2", link=[ROBOT])
        wait_until(lambda: back.robots(1.0) == [ROBOT], 20, "robot listed again")
        regained = robot.wait_event(lambda e: e.kind == "link_regained", 20, "link regained", after=start)
        assert "stays in force" in regained.detail
        state = robot.wait_state(lambda s: s.link == "up", 15, "link up in the state")
        assert [(t.kind, t.origin) for t in state.tasks] == [("hold", "failsafe")]
        assert state.waypoints_queued == 0
    finally:
        for g in (back, observer):
            if g is not None:
                g.close()
        if station is not None and station.poll() is None:
            station.kill()
            station.wait(10)
        if station is not None and station.stdout is not None:
            station.stdout.close()
        la.stop()
        la.cleanup()
