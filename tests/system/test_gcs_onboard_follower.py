"""Issue 15: a ground station asks for the onboard path follower (``follow_path --follower onboard``) on the
launched UAV (``bbcs_conf/uav1_sim.toml``): the Module Manager starts the path follower in mode 3, the DSP
simulator receives bridge references (SET_REFS) and never a waypoint for its own follower, the aircraft flies
near the path, and the ground station is told the task completed. A robot without the onboard follower refuses
it with the reason, and nothing reaches the DSP.
"""

from __future__ import annotations

import math
import sys
import threading
from pathlib import Path

from bbcs.contracts import gri
from bbcs.contracts import tasks as t
from bbcs.testing import wait_until
from ral.tasks import ONBOARD_TASK

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_command_path import Factory, barrier, ended, make_robot, names  # noqa: E402, F401
from test_gcs_mission import ROBOT, grid_path  # noqa: E402

M_PER_DEG = 111_320.0
MAX_XTRACK_M = 8.0
"""How far from the path the aircraft may be seen (1 Hz GRI states, corners flown at speed, gusts)."""


def local_m(lat: float, lon: float, ref: gri.Waypoint) -> tuple[float, float]:
    return (lat - ref.lat) * M_PER_DEG, (lon - ref.lon) * M_PER_DEG * math.cos(math.radians(ref.lat))


def cross_track_m(p: tuple[float, float], corners: list[tuple[float, float]]) -> float:
    """Distance from ``p`` to the polyline through ``corners`` (north, east metres)."""
    best = math.inf
    for (an, ae), (bn, be) in zip(corners, corners[1:], strict=False):
        dn, de = bn - an, be - ae
        length2 = dn * dn + de * de
        u = 0.0 if length2 == 0 else max(0.0, min(1.0, ((p[0] - an) * dn + (p[1] - ae) * de) / length2))
        best = min(best, math.hypot(p[0] - an - u * dn, p[1] - ae - u * de))
    return best


def test_gcs_follow_path_with_the_onboard_follower_flies_mode_3(make_robot: Factory) -> None:  # noqa: F811
    # in lockstep (docs/simulation.md): mode 3 sends SET_REFS every 50 ms of simulated time, acknowledged one by
    # one, and the acknowledgements' retry budget is on the same clock, so a loaded machine cannot starve it
    robot = make_robot(speed="max")
    start = len(robot.events)
    took_off = robot.gcs.send(ROBOT, t.TakeOff(height=10.0))
    assert took_off.accepted, took_off.reason
    assert ended(robot, took_off.task_id, 90, start).kind == "task_completed"
    up = robot.wait_state(lambda s: bool(s.airborne) and s.position is not None and s.home is not None
                          and s.position.alt >= s.home.alt + 8.0, 30, "airborne at the take-off height")
    assert up.position is not None
    path = grid_path(up.position, [(2, 0), (4, 0), (4, 2)])  # north 44 m, then east 18 m: one 90° turn
    seen: list[gri.GriState] = []
    lock = threading.Lock()

    def keep(state: gri.GriState) -> None:
        with lock:
            seen.append(state)

    mark = len(robot.commands())
    start = len(robot.events)
    with robot.gcs.watch(ROBOT, keep):
        reply = robot.gcs.send(ROBOT, t.FollowPath(waypoints=path, speed=5.0, follower="onboard"))
        assert reply.accepted, reply.reason
        done = ended(robot, reply.task_id, 120, start)
        # the 1 Hz state lags the completion event: judge where the aircraft ended from two states after it
        with lock:
            after = len(seen)
        wait_until(lambda: len(seen) >= after + 2, 15, "two states after the task ended")
    assert done.kind == "task_completed", done
    running = [e for e in robot.events[start:] if e.task_id == reply.task_id and e.kind == "task_accepted"]
    assert running, "the ground station was told the task started"

    sent = robot.commands()[mark:]
    n = names(sent)
    assert any(c["name"] == "SET_MODE" and c["fields"]["mode"] == 3 for c in sent), n
    refs = [c for c in sent if c["name"] == "SET_REFS"]
    assert len(refs) >= 20, f"only {len(refs)} SET_REFS from the onboard follower"
    assert "ADD_WAYPOINT" not in n, "mode 3 gave the DSP's own follower waypoints"
    assert "SET_SPEED" in n, "the task's speed reached the DSP (VELOCIDAD honoured in mode 3)"

    ref = path[0]
    corners = [local_m(up.position.lat, up.position.lon, ref)] + [local_m(w.lat, w.lon, ref) for w in path]
    with lock:
        track = [s.position for s in seen if s.position is not None]
    assert len(track) >= 5, f"only {len(track)} positions seen during the flight"
    xtrack = [cross_track_m(local_m(p.lat, p.lon, ref), corners) for p in track]
    assert max(xtrack) < MAX_XTRACK_M, f"cross-track up to {max(xtrack):.1f} m: {[round(x, 1) for x in xtrack]}"
    assert max(abs(p.alt - ref.alt) for p in track) < 3.0, "the altitude wandered off the path's"
    last = track[-1]
    end = local_m(last.lat, last.lon, ref)
    assert math.dist(end, corners[-1]) < 8.0, f"ended {math.dist(end, corners[-1]):.1f} m from the last waypoint"


def test_onboard_follower_on_a_robot_without_it_is_refused_and_nothing_reaches_the_dsp(
        make_robot: Factory) -> None:  # noqa: F811
    def without_onboard(manifest: str) -> str:
        head, sep, tail = manifest.partition(f"[tasks.{ONBOARD_TASK}]")
        assert sep, f"uav1_sim.toml has no [tasks.{ONBOARD_TASK}]"
        return head + tail[tail.index("\n[") + 1:]

    robot = make_robot(edit=without_onboard)
    state = robot.wait_state(lambda s: "follow_path" in s.available, 30, "follow_path offered")
    assert state.position is not None
    path = grid_path(state.position, [(2, 0), (2, 2)])
    mark = len(robot.commands())
    start = len(robot.events)
    reply = robot.gcs.send(ROBOT, t.FollowPath(waypoints=path, speed=5.0, follower="onboard"))
    assert not reply.accepted
    assert "onboard follower" in reply.reason and ONBOARD_TASK in reply.reason, reply.reason
    assert barrier(robot, mark) == [], "a refused task sent something to the DSP"
    assert not any(e.kind == "task_accepted" for e in robot.events[start:] if e.task_type == "movement")
    assert not any(x.task_type == "movement" for x in robot.state.tasks), "a movement task is running"
