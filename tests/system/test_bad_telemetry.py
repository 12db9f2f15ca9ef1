"""Issue 30 case 3 on the shipped ``bbcs_conf/uav1_sim.toml``: one DSP telemetry frame with latitude 200° and a good
CRC, injected through the simulator's control port during a goto, does not end the mission. The frame is refused and
reported once, as TELEMETRY_REFUSED on the DSP process's ERROR slot; no other module reports anything (no 1009 from
the path follower, no 603 from the RAL); the goto completes where it was asked to; the DSP received nothing because
of the bad frame; and nothing fails in the seconds after, when the RAL's persistence window has long passed."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from monitor_support import free_udp_port  # noqa: E402
from test_gcs_mission import ROBOT, SimRobot, connect, grid_path, launch_robot  # noqa: E402

from bbcs.contracts import gri
from bbcs.contracts.dsp import LinkErrorCode
from bbcs.testing import wait_until
from modules.dsp.sim.control import send_command
from ral.faults import TELEMETRY_FAULT_WINDOW_S
from ral.gcs.api import Gcs

REFUSED = ("dsp", int(LinkErrorCode.TELEMETRY_REFUSED))
WATCH_AFTER_S = 20.0
"""Simulated seconds watched after the goto ends (past the RAL's 3 s window and many states)."""


def with_control_port(port: int):
    def edit(text: str) -> str:
        old = '"--record"'
        assert text.count(old) == 1, "the test manifest's simulator command line changed"
        return text.replace(old, f'"--control", "127.0.0.1:{port}", "--record"')
    return edit


def errors_since(robot: SimRobot, since: float) -> list[tuple[str, int, float]]:
    """Every error the ground station was shown with a stamp from ``since`` on, once each (states repeat them)."""
    with robot.lock:
        states = list(robot.states)
    return sorted({(e.module, e.code, e.stamp) for s in states for e in s.errors if e.stamp >= since},
                  key=lambda e: e[2])


@contextmanager
def airborne(tmp_path: Path, cells_north: int) -> Iterator[tuple[SimRobot, Gcs, int, gri.Waypoint]]:
    """The robot in lockstep at --speed max with the DSP simulator's control port, airborne; yields it, its
    ground station, the control port and a goal ``cells_north`` grid cells north, 15 m above home."""
    control = free_udp_port()
    la, record = launch_robot(tmp_path, lockstep=True, edit=with_control_port(control))
    gcs = None
    try:
        gcs = connect(la.port, "ground1")
        robot = SimRobot(la, gcs, record)
        up = robot.ensure_airborne()
        assert up.position is not None and up.home is not None
        goal = grid_path(up.position, steps=[(cells_north, 0)])[0]
        yield robot, gcs, control, gri.Waypoint(lat=goal.lat, lon=goal.lon, alt=up.home.alt + 15.0)
    finally:
        if gcs is not None:
            gcs.close()
        la.stop()
        la.cleanup()


def test_one_bad_telemetry_frame_during_a_goto_does_not_end_it(tmp_path: Path) -> None:
    # 6 grid cells north: about 67 m, 13 s at 5 m/s
    with airborne(tmp_path, 6) as (robot, gcs, control, goal):
        since = robot.state.stamp  # the robot's clock (simulated time): the manager stamps its errors on it
        start = len(robot.events)
        reply = gcs.send(ROBOT, gri.Goto(waypoints=[goal], speed=5.0))
        assert reply.accepted, reply.reason
        robot.wait_state(lambda s: any(t.kind == "goto" for t in s.tasks) and bool(s.waypoints_queued), 20,
                         "the goto flying")
        n_before = len(robot.commands())
        assert send_command("127.0.0.1", control, "spoil position.lat=200") == "ok spoil position.lat=200.0 x1"
        wait_until(lambda: REFUSED in [(m, c) for m, c, _ in errors_since(robot, since)], 15,
                   "the refused frame reported on the GRI state")

        done = robot.wait_event(lambda e: e.task_id == reply.task_id and e.kind != "task_accepted", 60,
                                "the goto ended", after=start)
        assert done.kind == "task_completed", done
        assert send_command("127.0.0.1", control, "pending") == "ok pending 0 injected 1"
        # nothing reached the DSP because of the bad frame: no hold, no abort, no mode change while the goto flew
        during = [c["name"] for c in robot.commands()[n_before:]]
        assert not {"ABORT", "INVALIDATE_PATH", "SET_MODE", "SET_TRACKING"} & set(during), during
        end = robot.wait_state(lambda s: s.position is not None and not any(t.kind == "goto" for t in s.tasks),
                               15, "the goto gone from the state")
        assert end.position is not None
        assert abs(end.position.lat - goal.lat) * 111_320 < 8.0 and abs(end.position.alt - goal.alt) < 2.0

        # the RAL's persistence window passes with good telemetry: no late failure, no other error
        assert WATCH_AFTER_S > TELEMETRY_FAULT_WINDOW_S
        robot.wait_state(lambda s: s.stamp >= end.stamp + WATCH_AFTER_S, 60,
                         f"{WATCH_AFTER_S:g} simulated seconds after the goto")
        shown = [(m, c) for m, c, _ in errors_since(robot, since)]
        assert shown == [REFUSED], shown  # once, and nothing else: no 1009, no 603, no bus code
        with robot.lock:
            failed = [e for e in robot.events[start:] if e.kind == "task_failed"]
        assert not failed, failed


def test_refused_telemetry_that_persists_fails_the_goto_in_simulated_time(tmp_path: Path) -> None:
    """The other side of the same rule, in lockstep at --speed max: 6 s of refused frames (the DSP's 20 Hz
    telemetry, 120 frames) and nothing valid after them fail the goto once the refusal stood the RAL's window,
    judged on the robot's one clock (the manager's error stamps against the telemetry's: with the manager on the
    wall clock, behind simulated time, the refusal looked older than the last good frame and never stood)."""
    # 12 grid cells north: about 134 m, 27 s at 5 m/s, longer than the fault
    with airborne(tmp_path, 12) as (robot, gcs, control, goal):
        since = robot.state.stamp
        start = len(robot.events)
        reply = gcs.send(ROBOT, gri.Goto(waypoints=[goal], speed=5.0))
        assert reply.accepted, reply.reason
        robot.wait_state(lambda s: any(t.kind == "goto" for t in s.tasks) and bool(s.waypoints_queued), 20,
                         "the goto flying")
        assert send_command("127.0.0.1", control, "spoil position.lat=200 120") == "ok spoil position.lat=200.0 x120"
        wait_until(lambda: REFUSED in [(m, c) for m, c, _ in errors_since(robot, since)], 15,
                   "the refused frames reported on the GRI state")
        first_refused = min(s for m, c, s in errors_since(robot, since) if (m, c) == REFUSED)
        done = robot.wait_event(lambda e: e.task_id == reply.task_id and e.kind != "task_accepted", 60,
                                "the goto ended", after=start)
        assert done.kind == "task_failed" and "no valid telemetry" in done.detail, done
        assert done.stamp - first_refused >= TELEMETRY_FAULT_WINDOW_S, (done.stamp, first_refused)
