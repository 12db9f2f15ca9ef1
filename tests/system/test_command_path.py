"""Issue 11, one test per numbered case, on the launched UAV (``cromat launch bbcs_conf/uav1_sim.toml``: the
real Module Manager, RAL, modules and DSP simulator): what the DSP received (the simulator's record), its waypoint
queue and the aircraft's position (GRI state), and what the ground station was told (replies, GRI events).

Every test launches its own robot (free ports, its own record file), so they run in any order and in parallel.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from bbcs.contracts import gri, mri
from bbcs.contracts import tasks as t
from bbcs.testing import wait_until
from ral.gcs import cli

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_gcs_mission import MANIFEST, ROBOT, SimRobot, connect, grid_path, launch_robot  # noqa: E402

M_PER_DEG = 111_320.0
HOME_ALT = 12.0
"""The DSP simulator's ground level (m above sea level)."""

Factory = Callable[..., SimRobot]
MANIFEST_DIR = MANIFEST.parent


@pytest.fixture
def make_robot(tmp_path: Path) -> Iterator[Factory]:
    made: list[tuple[object, object]] = []

    def make(link: bool = True, speed: str | None = None, **manifest_kw: object) -> SimRobot:
        """A robot in lockstep, paced at the simulator's 4x (``speed=None``) or at ``--speed`` ``speed``."""
        la, record = launch_robot(tmp_path, speed=speed, lockstep=True, **manifest_kw)
        gcs = None
        try:
            gcs = connect(la.port, "ground1", link=link)
        finally:
            made.append((la, gcs))
        robot = SimRobot(la, gcs, record)
        robot.wait_state(lambda s: s.manager_up and s.position is not None and bool(s.available), 60,
                         "GRI state with position and task list")
        return robot

    yield make
    for la, gcs in made:
        if gcs is not None:
            gcs.close()  # type: ignore[attr-defined]
        la.stop()  # type: ignore[attr-defined]
        la.cleanup()  # type: ignore[attr-defined]


def names(cmds: list[dict]) -> list[str]:
    return [c["name"] for c in cmds]


def ended(robot: SimRobot, task_id: int, timeout_s: float, after: int = 0) -> gri.GriEvent:
    return robot.wait_event(lambda e: e.task_id == task_id and e.kind != "task_accepted", timeout_s,
                            f"task {task_id} ended", after=after)


def near(state: gri.GriState, wp: t.Waypoint, metres: float = 8.0) -> bool:
    pos = state.position
    return pos is not None and abs(pos.lat - wp.lat) * M_PER_DEG < metres and abs(pos.alt - wp.alt) < 3.0


def barrier(robot: SimRobot, mark: int) -> list[dict]:
    """Everything the DSP received after ``mark`` up to a pan & tilt task sent now (its SET_PT_MODE is the marker:
    anything a refused request had sent would be in the record before it)."""
    reply = robot.gcs.send(ROBOT, t.SetPanTilt(pan=5.0, tilt=-5.0))
    assert reply.accepted, reply.reason
    wait_until(lambda: "SET_PT_MODE" in names(robot.commands()[mark:]), 20, "the barrier at the DSP")
    cmds = robot.commands()[mark:]
    return cmds[: names(cmds).index("SET_PT_MODE")]


# ------------------------------------------------------------------ case 1: replace means replace


def test_case1_a_new_movement_task_replaces_the_path_in_both_queues(make_robot: Factory) -> None:
    robot = make_robot()
    up = robot.ensure_airborne()
    assert up.position is not None
    six = grid_path(up.position, [(i, 0) for i in range(1, 7)], scale=2)
    first = robot.gcs.send(ROBOT, t.FollowPath(waypoints=six, speed=5.0))
    assert first.accepted, first.reason
    robot.wait_state(lambda s: (s.waypoints_queued or 0) >= 5, 20, "the six-waypoint path in the DSP queue")
    mark = len(robot.commands())
    start = len(robot.events)
    two = grid_path(up.position, [(0, 2), (0, 4)])
    second = robot.gcs.send(ROBOT, t.Goto(waypoints=two, speed=5.0))
    assert second.accepted, second.reason
    replaced = ended(robot, first.task_id, 15, start)
    assert replaced.kind == "task_replaced" and f"task {second.task_id}" in replaced.detail
    robot.wait_state(lambda s: s.waypoints_queued is not None and s.waypoints_queued <= 2
                     and any(x.id == second.task_id for x in s.tasks), 15, "the DSP queue holds only the goto")
    done = ended(robot, second.task_id, 60, start)
    assert done.kind == "task_completed", done
    sent = robot.commands()[mark:]
    n = names(sent)
    cut = n.index("INVALIDATE_PATH")
    assert "ADD_WAYPOINT" not in n[:cut], "a new waypoint went out before the old queue was emptied"
    added = [(round(c["fields"]["lat"], 4), round(c["fields"]["lon"], 4)) for c in sent[cut:]
             if c["name"] == "ADD_WAYPOINT"]
    assert added == [(w.lat, w.lon) for w in two], "the DSP received exactly the goto's two waypoints"
    assert near(robot.wait_state(lambda s: near(s, two[-1]), 15, "at the goto's end"), two[-1])


# ------------------------------------------------------------------ case 2: the return failsafe replaces


def test_case2_return_failsafe_empties_the_mission_and_flies_home(make_robot: Factory) -> None:
    robot = make_robot(link=False, ral={"failsafe_action": "return", "failsafe_timeout_s": "1.5"})
    pilot = connect(robot.launch.port, "pilot")  # type: ignore[attr-defined]
    try:
        robot.wait_state(lambda s: s.link == "up", 30, "the pilot's link up")
        up = robot.ensure_airborne()
        home = up.home
        assert home is not None and up.position is not None
        mission = grid_path(up.position, [(i, 0) for i in range(1, 7)], scale=3)
        reply = robot.gcs.send(ROBOT, t.FollowPath(waypoints=mission, speed=5.0))
        assert reply.accepted, reply.reason
        robot.wait_state(lambda s: (s.waypoints_queued or 0) >= 4, 20, "mid-mission")
        mark = len(robot.commands())
        start = len(robot.events)
    finally:
        pilot.close()
    robot.wait_event(lambda e: e.kind == "failsafe", 20, "failsafe", after=start)
    lost = ended(robot, reply.task_id, 20, start)
    assert lost.kind == "task_replaced"
    back = robot.wait_event(lambda e: e.kind == "task_accepted" and "failsafe" in e.detail, 20, "return task",
                            after=start)
    wait_until(lambda: names(robot.commands()[mark:]).count("ADD_WAYPOINT") >= 1, 15, "home waypoint sent")
    sent = robot.commands()[mark:]
    cut = names(sent).index("INVALIDATE_PATH")
    assert "ADD_WAYPOINT" not in names(sent[:cut]), "the home waypoint went out before the mission was emptied"
    added = [c for c in robot.commands()[mark:] if c["name"] == "ADD_WAYPOINT"]
    assert len(added) == 1, "only the home waypoint: the mission is not flown after the link loss"
    assert abs(added[0]["fields"]["lat"] - home.lat) < 1e-4 and abs(added[0]["fields"]["lon"] - home.lon) < 1e-4
    done = ended(robot, back.task_id, 60, start)
    assert done.kind == "task_completed", done
    # the GRI state's telemetry lags the event (it comes with the manager's state): wait for it with a deadline
    robot.wait_state(lambda s: s.position is not None and abs(s.position.lat - home.lat) * M_PER_DEG < 8.0
                     and abs(s.position.lon - home.lon) * M_PER_DEG < 8.0, 15, "the aircraft home")


# ------------------------------------------------------------------ case 3: every path flies at a known speed


def test_case3_a_path_without_speed_flies_at_the_cruise_speed_also_after_a_dsp_restart(
    make_robot: Factory,
) -> None:
    robot = make_robot()
    up = robot.ensure_airborne()
    assert up.position is not None
    for round_ in ("fresh", "after a DSP restart"):
        state = robot.state
        assert state.position is not None
        target = grid_path(state.position, [(2, 0)])
        mark = len(robot.commands())
        start = len(robot.events)
        reply = robot.gcs.send(ROBOT, t.Goto(waypoints=target))
        assert reply.accepted, reply.reason
        done = ended(robot, reply.task_id, 60, start)
        assert done.kind == "task_completed", (round_, done)
        sent = robot.commands()[mark:]
        speeds = [c["fields"]["speed"] for c in sent if c["name"] == "SET_SPEED"]
        assert speeds == [pytest.approx(5.0)], f"{round_}: the DSP got speeds {speeds}, not CRUISE_SPEED 5"
        # speed before path (docs/gcs.md): the cruise speed reaches the DSP before the path's first waypoint
        assert names(sent).index("SET_SPEED") < names(sent).index("ADD_WAYPOINT"), names(sent)
        if round_ == "fresh":
            dsp = next(m for m in robot.gcs.modules(ROBOT).modules if m.name == "dsp")
            assert dsp.pid is not None
            os.kill(dsp.pid, signal.SIGKILL)
            # counted from before the kill: a start-up retry on a loaded machine may already have made it 1
            robot.wait_state(lambda s, before=dsp.restarts: any(
                m.name == "dsp" and m.state == "up" and m.restarts > before for m in s.modules), 60, "dsp restarted")


# ------------------------------------------------------------------ case 4: take-off height


def test_case4_take_off_height_the_dsp_cannot_honour_is_refused_and_its_own_is_reached(
    make_robot: Factory,
) -> None:
    robot = make_robot()
    mark = len(robot.commands())
    refused = robot.gcs.send(ROBOT, t.TakeOff(height=20.0))
    assert not refused.accepted and "take-off height 10 m" in refused.reason
    assert "SET_MODE" not in names(barrier(robot, mark)), "the refused take-off reached the DSP"
    start = len(robot.events)
    reply = robot.gcs.send(ROBOT, t.TakeOff(height=10.0))
    assert reply.accepted, reply.reason
    done = ended(robot, reply.task_id, 60, start)
    assert done.kind == "task_completed", done
    # the GRI state lags the event (the manager's state carries the telemetry): wait for one from after it
    state = robot.wait_state(lambda s: s.stamp > done.stamp + 1.5, 15, "a state after the completion")
    assert state.position is not None and state.home is not None
    assert state.position.alt - state.home.alt == pytest.approx(10.0, abs=2.0)


# ------------------------------------------------------------------ case 5: speed above MAX_SPEED


def test_case5_speed_above_max_speed_is_refused_before_anything_is_sent(make_robot: Factory) -> None:
    robot = make_robot()
    up = robot.ensure_airborne()
    assert up.position is not None
    target = grid_path(up.position, [(2, 0)])
    mark = len(robot.commands())
    refused = robot.gcs.send(ROBOT, t.Goto(waypoints=target, speed=12.0))
    assert not refused.accepted and "12 m/s is above MAX_SPEED 8 m/s" in refused.reason
    start = len(robot.events)
    before = barrier(robot, mark)
    assert "SET_SPEED" not in names(before) and "ADD_WAYPOINT" not in names(before)
    assert not any(e.task_type == "movement" for e in robot.events[start:]), "a movement task was started"
    robot.wait_event(lambda e: e.kind == "task_rejected" and "MAX_SPEED" in e.detail, 10, "task_rejected event")


# ------------------------------------------------------------------ case 6: a DSP restart fails the task


def test_case6_killing_the_dsp_mid_path_fails_the_task_and_nothing_resumes(make_robot: Factory) -> None:
    robot = make_robot()
    up = robot.ensure_airborne()
    assert up.position is not None
    path = grid_path(up.position, [(i, 0) for i in range(1, 7)], scale=3)
    reply = robot.gcs.send(ROBOT, t.FollowPath(waypoints=path, speed=5.0))
    assert reply.accepted, reply.reason
    robot.wait_state(lambda s: (s.waypoints_queued or 0) >= 4, 20, "mid-path")
    start = len(robot.events)
    dsp = next(m for m in robot.gcs.modules(ROBOT).modules if m.name == "dsp")
    assert dsp.pid is not None
    os.kill(dsp.pid, signal.SIGKILL)
    failed = ended(robot, reply.task_id, 20, start)
    assert failed.kind == "task_failed" and "dsp" in failed.detail, failed
    robot.wait_state(lambda s: not any(x.task_type == "movement" for x in s.tasks), 10, "no movement task shown")
    robot.wait_state(lambda s: any(m.name == "dsp" and m.state == "up" and m.restarts >= 1 for m in s.modules),
                     60, "dsp restarted")
    cmds = robot.commands()
    # a frame the DSP refused (one the killed process left half-written) is recorded without fields
    last_startup = max(i for i, c in enumerate(cmds) if c["name"] == "SET_SPEED" and c["fields"].get("speed") == 0)
    after = barrier(robot, last_startup)
    assert not {"ADD_WAYPOINT", "SET_MODE"} & set(names(after)), f"something resumed: {names(after)}"
    queued = robot.wait_state(lambda s: s.waypoints_queued == 0, 15, "the DSP queue empty after the restart")
    assert queued.position is not None and not near(queued, path[-1], 20.0)


# ------------------------------------------------------------------ case 7: clearance and altitude reference


def test_case7_a_waypoint_below_the_minimum_clearance_is_refused(make_robot: Factory) -> None:
    robot = make_robot()
    pos = robot.state.position
    assert pos is not None
    low = t.Goto(waypoints=[t.Waypoint(lat=round(pos.lat, 4) + 2e-4, lon=round(pos.lon, 4), alt=5.0)], speed=4.0)
    mark = len(robot.commands())
    refused = robot.gcs.send(ROBOT, low)
    assert not refused.accepted
    assert "5 m above sea level" in refused.reason and "minimum clearance" in refused.reason
    far = t.Goto(waypoints=[t.Waypoint(lat=pos.lat + 0.03, lon=pos.lon, alt=40.0)], speed=4.0)  # 3.3 km out
    fenced = robot.gcs.send(ROBOT, far)
    assert not fenced.accepted and "geofence" in fenced.reason
    assert "ADD_WAYPOINT" not in names(barrier(robot, mark))
    robot.wait_event(lambda e: e.kind == "task_rejected" and "clearance" in e.detail, 10, "task_rejected event")


# ------------------------------------------------------------------ case 8: the GCS link is per robot


def test_case8_watching_a_robot_that_does_not_exist_exits_3_and_is_no_link_for_uav1(
    make_robot: Factory, capsys: pytest.CaptureFixture[str]
) -> None:
    robot = make_robot(link=False, ral={"failsafe_timeout_s": "1", "heartbeat_timeout_s": "1"})
    t0 = time.monotonic()
    code = cli.main(["--connect", f"tcp/127.0.0.1:{robot.launch.port}", "--timeout", "2",  # type: ignore[attr-defined]
                     "watch", "uav2"])
    assert code == 3 and time.monotonic() - t0 < 12.0
    assert "no robot 'uav2' answered within 2 s" in capsys.readouterr().err
    # the link failsafe is judged on the wall clock (a ground station is outside the simulation): 3 wall seconds
    # past its 1 s timeout, then a state published after them: the link never came up, nothing fired
    time.sleep(3.0)
    seen = robot.received
    robot.wait_state(lambda s: robot.received > seen, 30, "a state 3 s after the watch ended")
    late = robot.state
    assert late.link == "no_gcs"
    assert not [e for e in robot.events if e.kind in ("link_up", "link_lost", "failsafe")]


# ------------------------------------------------------------------ case 9: replies tell the truth


def test_case9_a_mode_the_module_refuses_is_not_ok(make_robot: Factory, tmp_path: Path) -> None:
    # The path follower refuses mode 1 (heading from the HEADING slot) while no DSP telemetry has given it the
    # current heading (FollowerError.HEADING_UNKNOWN = 116): a robot whose .conf asks the DSP for neither HEADING
    # nor ATTITUDE (whose yaw would give it).
    conf = MANIFEST_DIR / "uav1.conf"
    blind = tmp_path / "uav1_no_heading.conf"
    text = conf.read_text()
    listed = "TELEMETRY: [POSITION, ATTITUDE, VELOCITY, ANGULAR_RATE, HEADING, STATUS,"
    assert listed in text, "uav1.conf's TELEMETRY list changed"
    blind.write_text(text.replace(listed, "TELEMETRY: [POSITION, VELOCITY, ANGULAR_RATE, STATUS,"))
    robot = make_robot(edit=lambda m: m.replace(f'conf = "{conf}"', f'conf = "{blind}"'))
    session = robot.gcs.session
    mark = len(robot.commands())
    reply = mri.call(session, ROBOT, "mode", mri.SetModuleMode(
        module="path_follower", mode={"modo_o_comando": 0, "modo_de_funcionamiento": 1}))
    assert not reply.ok and reply.code == 116 and "heading" in reply.reason, reply
    assert "SET_MODE" not in names(barrier(robot, mark))
    fine = mri.call(session, ROBOT, "mode", mri.SetModuleMode(
        module="path_follower", mode={"modo_o_comando": 0, "modo_de_funcionamiento": 2}))
    assert fine.ok and fine.code is None, fine
    wait_until(lambda: any(c["name"] == "SET_MODE" and c["fields"]["mode"] == 2 for c in robot.commands()[mark:]),
               15, "mode 2 at the DSP")


# ------------------------------------------------------------------ case 10: every task can be sent and seen


def test_case10_every_offered_task_can_be_sent_and_is_seen_whoever_started_it(make_robot: Factory) -> None:
    robot = make_robot()
    state = robot.state
    assert {"bridge", "follow_vision_path", "follow_path", "goto", "track"} <= set(state.available)
    assert "abort" not in state.available
    up = robot.ensure_airborne()
    assert up.position is not None
    # a task started through the MRI shows in the GRI, with an event
    start = len(robot.events)
    reply = mri.call(robot.gcs.session, ROBOT, "task", mri.SetTask(name="bridge", params=t.Bridge(ref_altitude=30.0)))
    assert reply.ok, reply.reason
    seen = robot.wait_event(lambda e: e.kind == "task_accepted" and "bridge" in e.detail, 15, "bridge announced",
                            after=start)
    robot.wait_state(lambda s: any(x.id == seen.task_id and x.origin == "mri" for x in s.tasks), 15,
                     "the MRI's bridge task in the GRI state")
    # the ground station sends bridge (REFS reach the DSP) and follow_vision_path
    mark = len(robot.commands())
    br = robot.gcs.send(ROBOT, t.Bridge(ref_altitude=up.position.alt + 2.0, error_longitudinal=1.0))
    assert br.accepted, br.reason
    wait_until(lambda: "SET_REFS" in names(robot.commands()[mark:]), 15, "REFS at the DSP")
    refs = next(c for c in robot.commands()[mark:] if c["name"] == "SET_REFS")
    assert refs["fields"]["error_longitudinal"] == pytest.approx(1.0)
    vision = robot.gcs.send(ROBOT, t.FollowVisionPath(speed=3.0))
    assert vision.accepted, vision.reason
    heading = robot.gcs.send(ROBOT, t.FollowPath(waypoints=grid_path(up.position, [(1, 0)]), heading=0.5))
    assert heading.accepted, heading.reason
    wait_until(lambda: any(c["name"] == "SET_MODE" and c["fields"]["mode"] == 1
                           for c in robot.commands()[mark:]), 15, "path mode 1 at the DSP")
    # module restart from the ground station; a task that needs a stopped module is refused with that reason
    pid = next(m.pid for m in robot.gcs.modules(ROBOT).modules if m.name == "pan_tilt")
    assert robot.gcs.restart(ROBOT, "pan_tilt").accepted
    again = next(m for m in robot.gcs.modules(ROBOT).modules if m.name == "pan_tilt")
    assert again.state == "up" and again.pid != pid, again
    stop = mri.call(robot.gcs.session, ROBOT, "module", mri.ModuleCommand(module="pan_tilt", action="stop"))
    assert stop.ok, stop.reason
    refused = robot.gcs.send(ROBOT, t.SetPanTilt(pan=1.0, tilt=1.0))
    assert not refused.accepted and "needs module pan_tilt, which is stopped" in refused.reason


# ------------------------------------------------------------------ case 11 on the launched robot (the race with
# an injected delay is in test_mode_data_order.py)


def out_of_mode(cmds: list[dict]) -> list[str]:
    """Pan & tilt data the DSP received under a mode that does not govern them (SPEC §3.2: angles only under
    mode 0, a target only under mode 1), replayed over the whole record."""
    mode, wrong = None, []
    for c in cmds:
        if c["name"] == "SET_PT_MODE":
            mode = c["fields"]["mode"]
        elif (c["name"], mode) in (("SET_PT_ANGLES", 1), ("SET_PT_ANGLES", 2), ("SET_PT_ANGLES", None),
                                   ("SET_PT_TARGET", 0), ("SET_PT_TARGET", 2), ("SET_PT_TARGET", None)):
            wrong.append(f"seq {c['seq']} {c['name']} under mode {mode}")
    return wrong


def test_case11_look_at_after_angles_never_sends_angles_under_the_old_mode(make_robot: Factory) -> None:
    robot = make_robot()
    reply = robot.gcs.send(ROBOT, t.SetPanTilt(pan=30.0, tilt=-20.0))
    assert reply.accepted, reply.reason
    wait_until(lambda: "SET_PT_ANGLES" in names(robot.commands()), 20, "angles at the DSP")
    for _ in range(5):  # look_at and back, a few times: every time, mode first, then the datum it governs
        mark = len(robot.commands())
        look = robot.gcs.send(ROBOT, t.LookAt(lat=37.4127, lon=-6.0025, alt=HOME_ALT))
        assert look.accepted, look.reason
        wait_until(lambda m=mark: "SET_PT_TARGET" in names(robot.commands()[m:]), 20, "the target at the DSP")
        assert out_of_mode(robot.commands()) == []
        mark = len(robot.commands())
        back = robot.gcs.send(ROBOT, t.SetPanTilt(pan=10.0, tilt=-10.0))
        assert back.accepted, back.reason
        wait_until(lambda m=mark: "SET_PT_ANGLES" in names(robot.commands()[m:]), 20, "angles at the DSP")
        assert out_of_mode(robot.commands()) == []
    # the last request's angles are what the pan & tilt ends on
    last = [c for c in robot.commands() if c["name"] in ("SET_PT_ANGLES", "SET_PT_TARGET")][-1]
    assert last["name"] == "SET_PT_ANGLES" and last["fields"]["pan_deg"] == 10.0, last
