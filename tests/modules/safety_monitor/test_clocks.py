"""One clock for the monitor: every stamp it compares turned into the robot's time (modules/safety_monitor/clocks.py),
and the lockstep frame a process's stamp may lag the physics by. The case that made a first attempt report false
breaches: in lockstep at --speed max the task book is stamped on the wall clock while the truth and the GRI are on
simulated time, so a completion stamped on the wall looked the aircraft up at another moment of the flight."""

from __future__ import annotations

import math
import re
import time

import pytest

from bbcs.clock import SimTime
from bbcs.context import ModuleContext
from bbcs.contracts import dsp as p
from bbcs.contracts import mri
from bbcs.contracts.dsp import DspSent
from bbcs.contracts.gri import GriState
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.contracts.tasks import Goto, TaskInfo, Waypoint
from bbcs.contracts.vehicle_truth import VehicleTruth
from bbcs.geodesy import metres_per_degree
from bbcs.lockstep import SimSettings, settings_env
from modules.safety_monitor.clocks import RobotTime, truth_behind
from modules.safety_monitor.logic import MonitorConfig, SafetyMonitor
from modules.safety_monitor.module import SafetyMonitorModule

HOME = (37.4117, -6.0025, 12.0)
M = 1 / metres_per_degree(HOME[0])[0]  # degrees of latitude per metre north, WGS84 (bbcs.geodesy)
EPOCH = 1_800_000_000.0


class Wall:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def test_a_wall_stamp_is_the_robot_time_in_force_then() -> None:
    wall = Wall(EPOCH + 30.0)
    robot = [EPOCH]
    rt = RobotTime(lambda: robot[0], simulated=True, wall=wall)
    for k in range(5):  # the robot came up 30 wall s after the epoch, then stepped 0.2 s every 0.04 wall s (5x)
        rt.note_step(SimTime(step=k, t=0.2 * k, epoch=EPOCH), wall=EPOCH + 30.0 + 0.04 * k)
    assert rt.from_wall(EPOCH + 30.05) == pytest.approx(EPOCH + 0.2)
    assert rt.from_wall(EPOCH + 30.0399) == pytest.approx(EPOCH)
    assert rt.from_wall(EPOCH + 99.0) == pytest.approx(EPOCH + 0.8)  # still the last step
    assert rt.from_wall(EPOCH + 29.0) == pytest.approx(EPOCH - 1.0)  # before any step: the wall's pace
    assert rt.truth(3.5) == pytest.approx(EPOCH + 3.5)
    rt.note_step(SimTime(step=2, t=0.4, epoch=EPOCH), wall=EPOCH + 31.0)  # an old publication changes nothing
    assert rt.from_wall(EPOCH + 31.0) == pytest.approx(EPOCH + 0.8)


def test_which_clock_a_source_stamps_on_is_learned_from_its_fresh_stamps() -> None:
    wall = Wall(EPOCH + 30.0)
    robot = [EPOCH + 0.8]
    rt = RobotTime(lambda: robot[0], simulated=True, wall=wall)
    rt.note_step(SimTime(step=4, t=0.8, epoch=EPOCH), wall=EPOCH + 29.9)
    rt.learn("manager", EPOCH + 29.99)  # a wall stamp written just now
    rt.learn("ral", EPOCH + 0.8)  # a robot-clock stamp
    assert rt.on_wall == {"manager": True, "ral": False}
    assert rt.stamp("manager", EPOCH + 29.95) == pytest.approx(EPOCH + 0.8)
    assert rt.stamp("ral", EPOCH + 0.6) == EPOCH + 0.6
    assert rt.stamp("new", EPOCH + 29.95) == pytest.approx(EPOCH + 0.8)  # undecided: the nearer clock
    wall.t = robot[0] + 1.0  # clocks too close to tell: nothing learned
    rt.learn("other", wall.t)
    assert "other" not in rt.on_wall


def test_without_lockstep_every_stamp_is_already_on_the_one_clock() -> None:
    rt = RobotTime(lambda: 5.0, simulated=False, wall=Wall(1e9))
    rt.learn("manager", 123.0)
    assert rt.stamp("manager", 123.0) == 123.0 and rt.from_wall(7.0) == 7.0 and rt.truth(3.0) is None


def truth_at(time_s: float, north_m: float, height: float = 20.0) -> VehicleTruth:
    return VehicleTruth(seq=int(time_s * 20), time_s=time_s, time_scale=1.0, home=HOME, lat=HOME[0] + north_m * M,
                        lon=HOME[1], alt=HOME[2] + height, vel_neu=(8.0, 0.0, 0.0), roll=0.0, pitch=0.0,
                        heading=0.0)


def goto_done(started: float, ended: float) -> TaskInfo:
    goal = Waypoint(lat=HOME[0] + 200 * M, lon=HOME[1], alt=HOME[2] + 20.0)
    return TaskInfo(id=2, name="goto", task_type="movement", kind="goto", params=Goto(waypoints=[goal], speed=8.0),
                    status="completed", started=started, ended=ended)


@pytest.fixture
def lockstep_module(monkeypatch: pytest.MonkeyPatch) -> SafetyMonitorModule:
    for k, v in settings_env(SimSettings(robot="uav1", speed="max")).items():  # as the manager starts it in lockstep
        monkeypatch.setenv(k, v)
    return SafetyMonitorModule(ModuleContext(robot="uav1", module="safety_monitor", conf=None, params={}))


def test_a_goto_completed_at_its_goal_in_lockstep_is_judged_on_the_robot_clock(
        lockstep_module: SafetyMonitorModule) -> None:
    """The simulation at 5x, up 30 wall s after its epoch: sim second t is stepped at wall epoch + 30 + t / 5 (so
    from sim 37.5 s on the robot's clock is ahead of the wall). The aircraft hovers, flies north at 8 m/s from sim
    75 s and reaches the goal (200 m) at sim 100 s, where the RAL completes the goto; the Module Manager stamps that
    on the wall: epoch + 50."""
    m = lockstep_module
    wall = Wall(EPOCH + 30.0)
    m.robot_time.wall = wall
    for k in range(0, 551):  # 110 sim s in frames of 0.2 s
        t = 0.2 * k
        wall.t = EPOCH + 30.0 + t / 5
        now = SimTime(step=k, t=t, epoch=EPOCH)
        m.robot_time.note_step(now, wall=wall.t)
        m.bbcs_clock.advance(now)  # type: ignore[attr-defined]
        for j in range(4):  # the truth of the frame the stepper just ran (kept every 0.05 s)
            ts = t - 0.15 + 0.05 * j
            if ts >= 0:
                m.monitor.on_truth(m.robot_time.truth(ts), truth_at(ts, north_m=min(200.0, max(0.0, 8.0 * (ts - 75)))))
    done = goto_done(EPOCH + 30.0 + 75.0 / 5, EPOCH + 50.0)
    m._on_book(m.clock(), mri.RobotState(robot="uav1", kind="uav", stamp=EPOCH + 50.1, ended=[done]))
    assert [b.kind for b in m.monitor.tick(m.clock() + 1.0)] == []
    assert m.monitor.counts["verdicts"] == 1
    # the same book taken as it is (wall stamps) beside the truth on the robot's clock, the reverted attempt:
    # epoch + 50 read as sim 50 s, when the aircraft still hovered 200 m short of the goal
    raw = SafetyMonitor(MonitorConfig(robot="uav1", stamp_lag_s=0.2))
    for s, tr in m.monitor.truth:
        raw.on_truth(s, tr)
    raw.on_book(EPOCH + 110.0, EPOCH + 50.1, [], [done])
    (b,) = raw.tick(EPOCH + 110.0)
    far = re.search(r"completed ([\d.]+) m from its goal", b.summary)
    assert b.kind == "completed_away_from_goal" and far is not None and abs(float(far.group(1)) - 200.0) < 0.5, \
        b.summary


def test_the_dsp_and_gri_stamps_are_turned_into_robot_time(lockstep_module: SafetyMonitorModule) -> None:
    m = lockstep_module
    wall = Wall(EPOCH + 60.0)
    m.robot_time.wall = wall
    now = SimTime(step=50, t=10.0, epoch=EPOCH)
    m.robot_time.note_step(now, wall=EPOCH + 59.0)
    m.bbcs_clock.advance(now)  # type: ignore[attr-defined]
    m.on_dsp_sent(DspSent(sender="path_follower", batch_id=3, command=p.Abort(), stamp=EPOCH + 59.9))
    assert m.monitor.sent[-1].msg.stamp == pytest.approx(EPOCH + 10.0)
    tel = RobotTelemetry(stamp=EPOCH + 10.0, position=GeoPoint(lat=HOME[0], lon=HOME[1], alt=HOME[2]), airborne=False)
    m._on_gri_state(m.clock(), GriState(robot="uav1", stamp=EPOCH + 10.0, telemetry=tel, errors=[
        mri.ErrorEvent(module="telemetry", code=3, stamp=EPOCH + 59.5),
        mri.ErrorEvent(module="ral", code=603, stamp=EPOCH + 9.8)]))
    assert sorted(s for s, _ in m.monitor._reports) == pytest.approx([EPOCH + 9.8, EPOCH + 10.0])


# ---------------------------------------------------------------- a robot-clock stamp may be a frame early


def lagged(stamp_lag_s: float) -> SafetyMonitor:
    return SafetyMonitor(MonitorConfig(robot="uav1", stamp_lag_s=stamp_lag_s))


@pytest.mark.parametrize(("lag", "breaches"), [(0.2, []), (0.0, ["gri_airborne"])])
def test_a_take_off_frame_stamped_with_the_previous_frames_time_is_not_a_wrong_airborne(
        lag: float, breaches: list[str]) -> None:
    """The frame measured at 10.15 s (0.25 m up) reached the telemetry module before the step to 10.2 s: stamped
    10.0, when the truth was still on the ground (and still 0.1 s later: more than the clocks' skew)."""
    m = lagged(lag)
    for i in range(201):
        ts = i * 0.05
        m.on_truth(ts, truth_at(ts, 0.0, height=0.0))
    tel = RobotTelemetry(stamp=10.0, position=GeoPoint(lat=HOME[0], lon=HOME[1], alt=HOME[2] + 0.25), airborne=True)
    m.on_gri_state(10.0, GriState(robot="uav1", stamp=10.0, telemetry=tel))
    assert m.tick(10.0) == [] and m.counts["gri_compared"] == 0  # before the truth of its frame: not judged yet
    for i in range(201, 221):
        ts = i * 0.05
        m.on_truth(ts, truth_at(ts, 0.0, height=max(0.0, 5.0 * (ts - 10.1))))
    assert [b.kind for b in m.tick(11.0)] == breaches
    assert m.counts["gri_compared"] == 1


def test_an_abort_one_frame_later_on_the_robot_clock_is_right_two_frames_is_late() -> None:
    for ack, late in ((10.2, False), (10.4, True)):
        m = lagged(0.2)
        abort = TaskInfo(id=4, name="abort", task_type="movement", status="completed", started=10.0, ended=10.2)
        m.on_book(10.2, 10.2, [], [abort])
        m.on_sent(ack, DspSent(sender="path_follower", batch_id=1, command=p.Abort(), stamp=ack))
        got = m.tick(13.0)
        assert [b.kind for b in got] == (["abort_late"] if late else []), ack
        if late:
            assert "400 ms" in got[0].summary and "200 ms of it the stamps' frame" in got[0].evidence[-1]


def test_a_completion_judged_on_the_truth_of_its_stamps_frame() -> None:
    """The RAL completed the goto on a frame measured up to 0.2 s after its stamp: the aircraft reached the goal's
    10 m within that frame."""
    m = lagged(0.2)
    for i in range(400):
        ts = i * 0.05
        m.on_truth(ts, truth_at(ts, north_m=min(200.0, 11.0 * ts)))  # 11 m/s: 10 m from the goal at 17.27 s
    goal_reached = (200.0 - 10.0) / 11.0
    ended = math.floor(goal_reached / 0.2) * 0.2
    m.on_book(ended, ended, [], [goto_done(0.0, ended)])
    assert m.tick(ended + 1.0) == []
    m0 = lagged(0.0)
    for s, tr in m.truth:
        m0.on_truth(s, tr)
    m0.on_book(ended, ended, [], [goto_done(0.0, ended)])
    assert [b.kind for b in m0.tick(ended + 1.0)] == ["completed_away_from_goal"]


def test_in_lockstep_the_next_tasks_waypoints_in_the_frame_of_the_end_are_not_the_goal() -> None:
    """Found by the campaign: a follow_path completed at its goal, and the survey sent on its completion put its
    first waypoint on the DSP's line in the same frame: both stamped with that frame's time, the survey's waypoint
    was taken for the path's goal (96 m away)."""
    for lag in (0.2, 0.0):
        m = lagged(lag)
        for i in range(300):
            ts = i * 0.05
            m.on_truth(ts, truth_at(ts, north_m=200.0))
        goal = p.AddWaypoint(lat=HOME[0] + 200 * M, lon=HOME[1], alt=HOME[2] + 20.0)
        survey = p.AddWaypoint(lat=HOME[0] + 300 * M, lon=HOME[1], alt=HOME[2] + 30.0)
        m.on_sent(1.0, DspSent(sender="path_follower", batch_id=1, command=goal, stamp=1.0))
        m.on_sent(10.0, DspSent(sender="path_follower", batch_id=2, command=survey, stamp=10.0 + (0.0 if lag else 0.3)))
        path = TaskInfo(id=2, name="follow_path", task_type="movement", kind="follow_path", status="completed",
                        started=0.8, ended=10.0)
        m.on_book(10.0, 10.0, [], [path])
        assert m.goal(path) == (goal.lat, goal.lon, goal.alt)
        assert m.tick(12.0) == [], lag


def test_in_lockstep_the_step_waits_until_its_truth_is_read(lockstep_module: SafetyMonitorModule) -> None:
    """The simulator sends a step's truth over UDP before it asks the step: the monitor answers busy until it has
    read the truth up to the step's time (a verdict is never made on a truth still in its socket)."""
    m = lockstep_module
    m.bbcs_clock.advance(SimTime(step=5, t=1.0, epoch=EPOCH))  # type: ignore[attr-defined]
    assert m.lockstep_busy() == ""  # no truth seen: none is waited for
    m._truth_read = (0.8, time.monotonic())
    assert m.lockstep_busy() == "truth read up to 0.80 s of 1.00 s"
    m._truth_read = (1.0, time.monotonic())
    assert m.lockstep_busy() == ""
    m._truth_read = (0.8, time.monotonic() - 3.0)  # silent for 3 wall s: not waited for
    assert m.lockstep_busy() == ""


def test_a_step_is_waited_for_until_its_truth_is_read_to_the_truths_own_period() -> None:
    """The DSP simulator sends a truth at every step's end: behind until that one is read. The uQuad simulator
    samples every 0.05 s at its 0.01 s frames: a step ending at 31.599999999999923 (sums of 0.2 s) whose last line
    came at 31.56 (its sums of 0.05 s an ulp past 31.55) is read; the line before it is not enough."""
    assert truth_behind(31.4, 31.6) and not truth_behind(31.6, 31.6)
    assert truth_behind(31.59, 31.6)  # the DSP simulator's truth: to the step's end
    end = 31.599999999999923
    assert not truth_behind(31.56, end, 0.05) and not truth_behind(31.55, end, 0.05)
    assert truth_behind(31.5, end, 0.05) and truth_behind(31.4, end, 0.05)
