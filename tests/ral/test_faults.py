"""The persistence rule for refused DSP telemetry (ral/faults.py), with an injected clock: one bad frame never fails
a task; a fault with no valid telemetry after it for the window fails the running tasks the DSP serves, once. Then
the RAL process itself, against the stand-in manager: its hook applies the rule."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from bbcs.contracts import mri
from bbcs.contracts.dsp import LinkErrorCode
from bbcs.contracts.robot import RobotTelemetry
from bbcs.contracts.tasks import TaskInfo
from bbcs.testing import wait_until
from ral import faults
from ral.faults import TELEMETRY_FAULT_WINDOW_S, TelemetryFault, is_telemetry_refusal, judge, step

REFUSED = int(LinkErrorCode.TELEMETRY_REFUSED)


def refusal(stamp: float) -> mri.ErrorEvent:
    return mri.ErrorEvent(module="dsp", code=REFUSED, stamp=stamp)


class Robot:
    """The manager's state as the RAL sees it, once a second: telemetry stamps and the bounded error list."""

    def __init__(self) -> None:
        self.errors: list[mri.ErrorEvent] = []
        self.telemetry_stamp: float | None = None
        self.state = TelemetryFault()
        self.fails: list[tuple[float, str]] = []

    def tick(self, now: float) -> None:
        verdict = step(self.state, self.errors[-20:], self.telemetry_stamp, now)
        self.state = verdict.state
        if verdict.fail is not None:
            self.fails.append((now, verdict.fail))


def test_one_refused_frame_among_good_ones_never_fails_a_task() -> None:
    robot = Robot()
    for second in range(60):
        now = 1000.0 + second
        robot.telemetry_stamp = now - 0.05  # good frames all along
        if second == 10:
            robot.errors.append(refusal(now - 0.5))  # the bad frame, between two good ones
        robot.tick(now)
    assert robot.fails == []
    assert robot.state.pending is None and robot.state.seen == 1009.5


def test_refused_frames_and_no_valid_telemetry_fail_once_after_the_window() -> None:
    robot = Robot()
    robot.telemetry_stamp = 999.9  # the last good frame; from 1000.0 every frame is refused
    for tenth in range(0, 200):
        now = 1000.0 + tenth / 10
        if tenth % 10 == 0:  # the DSP process reports the run at most once a second
            robot.errors.append(refusal(now))
        robot.tick(now)
    assert len(robot.fails) >= 1
    first_at, reason = robot.fails[0]
    assert first_at == 1000.0 + TELEMETRY_FAULT_WINDOW_S  # noticed at 1000.0, failed 3 s later, not before
    assert "TELEMETRY_REFUSED" in reason and "no valid telemetry" in reason
    # a fault that goes on is judged again from the next refusal: a new task does not fly blind either
    assert [round(t - first_at, 1) for t, _ in robot.fails[:3]] == [0.0, 4.0, 8.0]


def test_valid_telemetry_within_the_window_clears_the_fault() -> None:
    robot = Robot()
    robot.telemetry_stamp = 999.9
    robot.errors.append(refusal(1000.0))
    robot.tick(1000.2)
    assert robot.state.pending == 1000.0
    robot.tick(1002.0)  # still nothing valid, still within the window
    robot.telemetry_stamp = 1002.5  # a good frame after the refused ones
    robot.tick(1003.0)
    robot.tick(1010.0)
    assert robot.fails == [] and robot.state.pending is None


def test_a_refusal_reported_after_newer_valid_telemetry_is_no_fault() -> None:
    """The report comes late (a loaded machine), but a good frame newer than it is already in: nothing pending."""
    state = step(TelemetryFault(), [refusal(1000.0)], 1000.4, now=1001.0).state
    assert state.pending is None
    assert step(state, [refusal(1000.0)], 1000.4, now=1010.0).fail is None  # the same report is not taken twice


def test_the_window_is_measured_on_the_rals_clock_whatever_the_stamps() -> None:
    """Stamps from a clock far from the RAL's: the window runs from when the RAL saw the refusal."""
    state = step(TelemetryFault(), [refusal(5.0)], 4.0, now=1_000_000.0).state
    assert step(state, [], 4.0, now=1_000_002.9).fail is None
    assert step(state, [], 4.0, now=1_000_003.0).fail is not None


def test_only_the_dsp_telemetry_refusal_is_judged_here() -> None:
    assert is_telemetry_refusal(refusal(1.0))
    assert not is_telemetry_refusal(mri.ErrorEvent(module="dsp", code=int(LinkErrorCode.LINK_DOWN), stamp=1.0))
    assert not is_telemetry_refusal(mri.ErrorEvent(module="path_follower", code=REFUSED, stamp=1.0))
    assert not is_telemetry_refusal(mri.ErrorEvent(module="path_follower", code=1009, stamp=1.0))
    others = [mri.ErrorEvent(module="dsp", code=int(LinkErrorCode.LINK_DOWN), stamp=10.0),
              mri.ErrorEvent(module="path_follower", code=1009, stamp=10.0)]
    state = step(TelemetryFault(), others, None, now=10.0).state
    assert step(state, others, None, now=100.0).fail is None  # others fail tasks elsewhere, at once


def test_judge_fails_only_the_running_tasks_of_the_types_the_dsp_serves() -> None:
    modules = [mri.ModuleStatus(name="dsp", state="up", task_types=["movement", "pan_tilt"]),
               mri.ModuleStatus(name="vision", state="up", task_types=["perception"])]
    running = [TaskInfo(id=1, name="goto", task_type="movement"), TaskInfo(id=2, name="track", task_type="perception"),
               TaskInfo(id=3, name="look_at", task_type="pan_tilt")]

    def state_at(stamp: float) -> mri.RobotState:
        return mri.RobotState(robot="uav1", kind="uav", stamp=stamp, modules=modules, errors=[refusal(100.0)],
                              telemetry=RobotTelemetry(stamp=99.0))

    fault, ends = judge(TelemetryFault(), state_at(100.0), running, now=100.0)
    assert ends == []
    fault, ends = judge(fault, state_at(102.0), running, now=102.0)
    assert ends == []
    fault, ends = judge(fault, state_at(103.0), running, now=103.0)
    assert [(e.task_type, e.task_id, e.status) for e in ends] == [("movement", 1, "failed"), ("pan_tilt", 3, "failed")]
    assert all("no valid telemetry after it for 3 s" in e.detail for e in ends)
    assert judge(fault, state_at(104.0), running, now=110.0)[1] == []  # once per refusal, not at every state
    assert faults.TELEMETRY_FAULT_WINDOW_S == 3.0  # docs/error_codes.md and docs/dsp_protocol.md say 3 s


# --- the RAL process against the stand-in manager (tests/ral/standin.py): the hook in ral/module.py ------------

sys.path.insert(0, str(Path(__file__).resolve().parent))
from standin import ROBOT as ROBOT_NAME  # noqa: E402
from test_module import Rig, rig, ten_waypoints  # noqa: E402, F401  (rig: the RAL and a stand-in manager)

DSP_UP = [mri.ModuleStatus(name="dsp", state="up", task_types=["movement", "pan_tilt"])]


def failed(ral: Rig, task_id: int) -> list:
    return [e for e in list(ral.events) if e.kind == "task_failed" and e.task_id == task_id]


def test_the_ral_fails_a_goto_only_when_refused_telemetry_persists(rig: Rig) -> None:  # noqa: F811
    goto = rig.gcs.send(ROBOT_NAME, ten_waypoints())
    assert goto.accepted, goto.reason
    # one refused frame, valid telemetry before and after it: the goto flies on
    t0 = time.time()
    rig.manager.tel = RobotTelemetry(stamp=t0 - 0.1)
    rig.manager.publish_state(modules=DSP_UP, errors=[refusal(t0)])
    deadline = time.time() + TELEMETRY_FAULT_WINDOW_S + 1.5
    while time.time() < deadline:
        rig.manager.tel = RobotTelemetry(stamp=time.time())
        rig.manager.publish_state(modules=DSP_UP, errors=[refusal(t0)])
        time.sleep(0.2)
    assert failed(rig, goto.task_id) == [] and rig.manager.end_tasks() == []
    # refused frames and nothing valid after them: failed after the window, with the reason
    t1 = time.time()
    stale = RobotTelemetry(stamp=t1 - 0.1)
    rig.manager.tel = stale
    errors = [refusal(t0), refusal(t1)]
    while time.time() < t1 + TELEMETRY_FAULT_WINDOW_S - 0.5:
        rig.manager.publish_state(modules=DSP_UP, errors=errors)
        time.sleep(0.2)
    assert failed(rig, goto.task_id) == []  # not before the window
    wait_until(lambda: (rig.manager.publish_state(modules=DSP_UP, errors=errors), failed(rig, goto.task_id))[1],
               10, "the goto failed once the fault persisted")
    end = rig.manager.end_tasks()[-1]
    assert (end.task_id, end.status) == (goto.task_id, "failed") and "no valid telemetry" in end.detail
    assert time.time() - t1 >= TELEMETRY_FAULT_WINDOW_S


LOW_BATTERY = 1000 + 7  # the DSP's LOW_BATTERY, forwarded by the path follower


def test_a_low_battery_fails_a_goto_but_not_the_landing_that_answers_it() -> None:
    land = TaskInfo(id=1, name="land", task_type="movement", kind="land")
    goto = TaskInfo(id=2, name="goto", task_type="movement", kind="goto")
    assert faults.answers_fault(land, LOW_BATTERY)
    assert not faults.answers_fault(goto, LOW_BATTERY)
    assert not faults.answers_fault(land, 1000 + 6)  # another DSP fault still fails a landing


def test_the_ral_keeps_a_landing_on_a_low_battery_and_fails_a_goto(rig: Rig) -> None:  # noqa: F811
    from bbcs.contracts import gri

    follower = [mri.ModuleStatus(name="path_follower", state="up", task_types=["movement"])]
    land = rig.gcs.send(ROBOT_NAME, gri.Land())
    assert land.accepted, land.reason
    t0 = time.time()
    low = [mri.ErrorEvent(module="path_follower", code=LOW_BATTERY, stamp=t0 + 0.05)]
    deadline = time.time() + 2.0
    while time.time() < deadline:
        rig.manager.publish_state(modules=follower, errors=low)
        time.sleep(0.2)
    assert failed(rig, land.task_id) == [] and rig.manager.end_tasks() == []
    goto = rig.gcs.send(ROBOT_NAME, ten_waypoints())
    assert goto.accepted, goto.reason
    low = [mri.ErrorEvent(module="path_follower", code=LOW_BATTERY, stamp=time.time() + 0.05)]
    wait_until(lambda: (rig.manager.publish_state(modules=follower, errors=low), failed(rig, goto.task_id))[1],
               10, "the goto failed on the low battery")
    assert "1007" in rig.manager.end_tasks()[-1].detail
