"""The flight-safety monitor's decisions, with its clock in the test's hands: for every invariant a flight that
breaches it and one that does not."""

from __future__ import annotations

import math
import re

import pytest

from bbcs.contracts import dsp as p
from bbcs.contracts import mri
from bbcs.contracts.dsp import DspSent
from bbcs.contracts.gri import GriEvent, GriState
from bbcs.contracts.mri import ErrorEvent
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.contracts.safety import Breach, Invariant, Severity
from bbcs.contracts.tasks import Goto, TakeOff, TaskInfo, Waypoint
from bbcs.contracts.vehicle_truth import VehicleTruth
from bbcs.geodesy import metres_per_degree
from modules.safety_monitor.logic import MonitorConfig, SafetyMonitor, ground_distance_m, is_stop

HOME = (37.4117, -6.0025, 12.0)
M = 1 / metres_per_degree(HOME[0])[0]  # degrees of latitude per metre north, WGS84 (bbcs.geodesy)


def monitor(**kw: object) -> SafetyMonitor:
    return SafetyMonitor(MonitorConfig(robot="uav1", geofence=(HOME[0], HOME[1], 3000.0), min_clearance_m=5.0,
                                       **kw))  # type: ignore[arg-type]


def task(id: int, name: str, started: float, ended: float | None = None, *, task_type: str = "movement",
         status: str = "running", params: object = None, kind: str | None = None, detail: str = "",
         origin: str = "gcs") -> TaskInfo:
    return TaskInfo(id=id, name=name, task_type=task_type, kind=name if kind is None else kind, params=params,
                    status=status if ended is None or status != "running" else "completed", started=started,
                    ended=ended, detail=detail, origin=origin)  # type: ignore[arg-type]


def book(m: SafetyMonitor, now: float, *tasks: TaskInfo) -> None:
    m.on_book(now, now, [t for t in tasks if t.ended is None], [t for t in tasks if t.ended is not None])


def sent(m: SafetyMonitor, stamp: float, cmd: object, sender: str = "path_follower", batch: int = 2) -> None:
    """``batch`` 1 is the first batch a process of ``sender`` sends."""
    m.on_sent(stamp, DspSent(sender=sender, batch_id=batch, command=cmd, stamp=stamp))  # type: ignore[arg-type]


def truth(m: SafetyMonitor, now: float, north_m: float = 0.0, height: float = 10.0, *, roll: float = 0.0,
          heading: float = 0.0, vup: float = 0.0, east_m: float = 0.0) -> None:
    m.on_truth(now, VehicleTruth(seq=int(now * 20), time_s=now, time_scale=1.0, home=HOME,
                                 lat=HOME[0] + north_m * M, lon=HOME[1] + east_m * M / math.cos(math.radians(HOME[0])),
                                 alt=HOME[2] + height, vel_neu=(0.0, 0.0, vup), roll=roll, pitch=0.0, heading=heading))


def telemetry(m: SafetyMonitor, now: float, *, north_m: float = 0.0, height: float = 10.0, queue: int = 0,
              nav_m: float | None = None, airborne: bool = True) -> None:
    lat = HOME[0] + north_m * M
    nav = p.NavTarget(lat=HOME[0] + 200 * M, lon=HOME[1], alt=HOME[2] + height, distance=nav_m) if nav_m else None
    m.on_telemetry(now, p.Telemetry(time_ms=int(now * 1000), position=p.TelPosition(lat=lat, lon=HOME[1],
                                                                                  alt=HOME[2] + height),
                                    status=p.DspStatus(mode=0, tracking=True, path_valid=True, airborne=airborne,
                                                       queue_length=queue), nav=nav))


def run(m: SafetyMonitor, until: float, step: float = 0.5) -> list[Breach]:
    out: list[Breach] = []
    t = 0.0
    while t <= until:
        out += m.tick(t)
        t += step
    return out


def kinds(breaches: list[Breach]) -> list[str]:
    return [b.kind for b in breaches]


# ---------------------------------------------------------------- 1. every command traced


def test_a_command_inside_its_task_is_traced() -> None:
    m = monitor()
    sent(m, 10.2, p.SetMode(mode=p.Mode.TAKE_OFF))
    book(m, 10.5, task(1, "take_off", 10.0))
    assert run(m, 20) == []
    assert m.counts["commands_judged"] == 1


def test_a_command_after_its_task_ended_is_a_critical_breach() -> None:
    """Issue 30 case 1: the task ends, then the previous mode is flown again."""
    m = monitor()
    book(m, 30.0, task(1, "land", 10.0, 25.0, status="completed"))
    sent(m, 25.3, p.SetMode(mode=p.Mode.TAKE_OFF))
    (b,) = run(m, 40)
    assert (b.invariant, b.kind, b.severity) == (Invariant.COMMAND_TRACED, "untraced_command", Severity.CRITICAL)
    assert "SetMode" in b.summary and any("1 land completed" in line for line in b.evidence)


def test_in_lockstep_a_command_stamped_a_frame_before_its_task_started_is_the_tasks() -> None:
    """A process's clock moves to a frame's time when its loop takes the frame's ask: the DSP process may stamp a
    command for a task the manager started at frame k with frame k-1's time. One frame, not more; on a robot (one
    wall clock) not at all."""
    lockstep = monitor(stamp_lag_s=0.2)
    book(lockstep, 30.0, task(1, "take_off", 10.0))
    sent(lockstep, 9.8, p.SetMode(mode=p.Mode.TAKE_OFF))
    assert run(lockstep, 40) == []
    sent(lockstep, 9.5, p.SetMode(mode=p.Mode.TAKE_OFF))
    assert kinds(run(lockstep, 40)) == ["untraced_command"]
    robot = monitor()
    book(robot, 30.0, task(1, "take_off", 10.0))
    sent(robot, 9.8, p.SetMode(mode=p.Mode.TAKE_OFF))
    assert kinds(run(robot, 40)) == ["untraced_command"]


def test_a_stop_command_at_a_task_end_is_traced_but_not_a_motion_command() -> None:
    m = monitor()
    book(m, 30.0, task(1, "goto", 10.0, 25.0, status="completed"))
    sent(m, 25.4, p.InvalidatePath())
    sent(m, 25.5, p.SetTracking(enable=False))
    assert run(m, 40) == []
    sent(m, 25.6, p.SetTracking(enable=True))
    assert kinds(run(m, 40)) == ["untraced_command"]


def test_the_pan_tilt_mode_restored_at_a_task_end_is_traced_but_not_a_pointing_command() -> None:
    """The campaign's `kill module=pan_tilt` (seed 7, sequence 21): the look_at task failed with the module, and
    the restarted module applied the mode the manager restored 1.6 s later. Pointing at a target then is not a
    restore; nor is a mode set long after."""
    m = monitor()
    book(m, 30.0, task(1, "look_at", 10.0, 25.0, task_type="pan_tilt", status="failed"))
    sent(m, 26.6, p.SetPanTiltMode(mode=p.PanTiltMode.TARGET), sender="pan_tilt")
    assert run(m, 40) == []
    sent(m, 26.7, p.SetPanTiltTarget(lat=HOME[0], lon=HOME[1], alt=12.0), sender="pan_tilt")
    sent(m, 29.0, p.SetPanTiltMode(mode=p.PanTiltMode.TARGET), sender="pan_tilt")
    assert [(b.kind, b.severity) for b in run(m, 40)] == [("untraced_command", Severity.ERROR)] * 2


def test_a_command_from_a_sender_that_serves_no_running_task_is_untraced() -> None:
    m = monitor()
    book(m, 5.0, task(1, "goto", 1.0))  # a movement task runs: it is behind no pan & tilt command
    sent(m, 6.0, p.SetPanTiltAngles(pan_deg=10.0, tilt_deg=-10.0), sender="pan_tilt")
    sent(m, 6.0, p.SetMode(mode=p.Mode.TAKE_OFF), sender="bench")  # the shared key's self-named sender
    assert [(b.kind, b.severity) for b in run(m, 20)] == [("untraced_command", Severity.ERROR),  # the gimbal
                                                           ("untraced_command", Severity.CRITICAL)]  # the aircraft


def test_start_up_holds_are_traced_only_before_the_first_task() -> None:
    m = monitor()
    sent(m, 1.0, p.SetPanTiltMode(mode=p.PanTiltMode.HOLD), sender="pan_tilt")
    book(m, 12.0, task(1, "take_off", 10.0))
    assert run(m, 20) == []
    sent(m, 13.0, p.SetPanTiltMode(mode=p.PanTiltMode.HOLD), sender="pan_tilt")
    (b,) = run(m, 30)
    assert b.severity is Severity.WARNING  # a hold nothing asked for: wrong, but it moves nothing


def test_the_mode_a_restarted_module_applies_first_is_its_start_up_not_what_it_sends_next() -> None:
    """The campaign's `take_off; done s=90; kill module=pan_tilt`: the restarted pan & tilt module applied the
    mode the manager keeps for it (the gimbal's rest mode), its process's first batch. A pointing command in that
    batch, or the same mode in a later one, is not a start-up."""
    m = monitor()
    book(m, 12.0, task(1, "take_off", 10.0, 11.0, status="completed"))
    sent(m, 30.0, p.SetPanTiltMode(mode=p.PanTiltMode.HOLD), sender="pan_tilt", batch=1)
    assert run(m, 40) == []
    sent(m, 41.0, p.SetPanTiltAngles(pan_deg=5.0, tilt_deg=0.0), sender="pan_tilt", batch=1)
    sent(m, 42.0, p.SetPanTiltMode(mode=p.PanTiltMode.HOLD), sender="pan_tilt", batch=2)
    assert [(b.kind, b.severity) for b in run(m, 60)] == [("untraced_command", Severity.ERROR),
                                                           ("untraced_command", Severity.WARNING)]


def test_a_restarted_manager_numbering_its_tasks_again_is_a_new_book() -> None:
    m = monitor()
    book(m, 20.0, task(1, "take_off", 10.0, 15.0, status="completed"))
    m.on_book(40.0, 40.0, [task(1, "goto", 30.0)], [], epoch=35.0)  # task 1 again, of the new book
    sent(m, 31.0, p.SetMode(mode=p.Mode.PATH_AUTO_HEADING))
    assert run(m, 50) == [] and len(m.tasks) == 2


def test_a_command_is_judged_only_once_the_task_book_could_show_its_task() -> None:
    m = monitor()
    sent(m, 10.1, p.SetMode(mode=p.Mode.PATH_AUTO_HEADING))
    assert m.tick(10.2) == []  # the book has not caught up: nothing decided yet
    book(m, 10.2, task(7, "goto", 10.0))  # the book is older than the command + lag: still waiting
    assert m.tick(10.3) == [] and m.counts["commands_judged"] == 0
    book(m, 10.5, task(7, "goto", 10.0))
    assert m.tick(10.5) == [] and m.counts["commands_judged"] == 1


# ---------------------------------------------------------------- 2. verdicts


def goto_task(ended: float | None, status: str = "completed", detail: str = "") -> TaskInfo:
    wp = Waypoint(lat=HOME[0] + 100 * M, lon=HOME[1], alt=HOME[2] + 20)
    return task(3, "goto", 10.0, ended, status=status, params=Goto(waypoints=[wp]), detail=detail)


def test_a_goto_completed_at_its_goal_is_right() -> None:
    m = monitor()
    sent(m, 10.1, p.AddWaypoint(lat=HOME[0] + 100 * M, lon=HOME[1], alt=HOME[2] + 20))
    truth(m, 30.0, north_m=98.0, height=20.5)
    book(m, 30.0, goto_task(30.0))
    assert run(m, 40) == []
    assert m.counts["verdicts"] == 1


def test_a_goto_completed_away_from_its_goal_is_a_breach() -> None:
    m = monitor()
    sent(m, 10.1, p.AddWaypoint(lat=HOME[0] + 100 * M, lon=HOME[1], alt=HOME[2] + 20))
    truth(m, 30.0, north_m=40.0, height=20.0)
    book(m, 30.0, goto_task(30.0))
    (b,) = run(m, 40)
    assert (b.invariant, b.kind, b.task_id) == (Invariant.TASK_VERDICT, "completed_away_from_goal", 3)
    far = re.search(r"completed ([\d.]+) m from its goal", b.summary)
    assert far is not None and abs(float(far.group(1)) - 60.0) < 0.5, b.summary


def test_take_off_and_land_verdicts() -> None:
    m = monitor()
    truth(m, 20.0, height=4.0)
    book(m, 20.0, task(1, "take_off", 10.0, 20.0, params=TakeOff(height=10.0)))
    truth(m, 50.0, height=0.0)
    book(m, 50.0, task(2, "land", 30.0, 50.0))
    assert kinds(run(m, 60)) == ["completed_away_from_goal"]  # the take-off at 4 m of 10; the landing is right
    m2 = monitor()
    truth(m2, 50.0, height=6.0)
    book(m2, 50.0, task(2, "land", 30.0, 50.0))
    assert [b.summary for b in run(m2, 60)] == ["task 2 land: land completed while airborne"]


def test_a_task_failed_while_waypoints_are_being_reached_is_a_breach() -> None:
    """Issue 30 case 2: 'no progress' while flying at 5 m/s with waypoints queued."""
    m = monitor()
    for i in range(21):  # 10 s: the nav distance shrinks, a waypoint is reached
        telemetry(m, 20.0 + i / 2, queue=3 if i < 10 else 2, nav_m=100.0 - 2.5 * i)
    book(m, 30.0, goto_task(30.0, status="failed", detail="no progress for 30 s"))
    (b,) = run(m, 40)
    assert (b.kind, b.severity) == ("failed_while_progressing", Severity.ERROR)
    assert any("waypoint queue 3 -> 2" in line for line in b.evidence)


def test_a_task_failed_while_hovering_in_place_is_not_a_breach() -> None:
    m = monitor()
    for i in range(21):
        telemetry(m, 20.0 + i / 2, queue=3, nav_m=100.0)
    book(m, 30.0, goto_task(30.0, status="failed", detail="no progress for 30 s"))
    assert run(m, 40) == []


def test_a_task_failed_with_its_module_is_judged_by_whether_the_aircraft_then_stops() -> None:
    """The DSP link killed mid-path (issue 11 case 6): the task fails at once ("its effect is lost") while the DSP
    still flies its queue, which is no breach; the restarted link's start-up stops the aircraft, and flying on
    15 s later is one."""
    lost = "module dsp exited (-9): the task's effect is lost"
    stopped = monitor()
    for i in range(61):  # flying from 20 s, the failure at 30, the restarted link stops it at 33
        telemetry(stopped, 20.0 + i / 2, queue=3 if i < 10 else 2, nav_m=100.0 - 2.5 * min(i, 26))
    book(stopped, 30.0, goto_task(30.0, status="failed", detail=lost))
    assert run(stopped, 40) == [], "judged only once the link had time to stop the aircraft"
    assert run(stopped, 50) == []
    flew_on = monitor()
    for i in range(61):  # the same failure, the aircraft still closing on its waypoint 15 s later
        telemetry(flew_on, 20.0 + i / 2, queue=3 if i < 10 else 2, nav_m=200.0 - 2.5 * i)
    book(flew_on, 30.0, goto_task(30.0, status="failed", detail=lost))
    (b,) = run(flew_on, 50)
    assert (b.kind, b.severity, b.task_id) == ("flew_on_after_failure", Severity.ERROR, 3)
    assert any("distance to the nav target" in line for line in b.evidence), b.evidence
    taken_over = monitor()  # campaign seed 41, sequence 77: a new task of its type flies the aircraft on
    for i in range(61):
        telemetry(taken_over, 20.0 + i / 2, queue=3 if i < 10 else 2, nav_m=200.0 - 2.5 * i)
    book(taken_over, 33.0, goto_task(30.0, status="failed", detail=lost),
         task(4, "goto", 33.0, None, params=Goto(waypoints=[Waypoint(lat=HOME[0], lon=HOME[1], alt=HOME[2] + 20)])))
    assert run(taken_over, 50) == [], "the new task's flight is not the failed one's"
    same_frame = monitor()  # campaign seed 41, sequence 64: in lockstep the next task started in the failure's frame
    for i in range(61):
        telemetry(same_frame, 20.0 + i / 2, queue=3 if i < 10 else 2, nav_m=200.0 - 2.5 * i)
    book(same_frame, 30.0, goto_task(30.0, status="failed", detail=lost),
         task(4, "orbit", 30.0, None, params=Goto(waypoints=[Waypoint(lat=HOME[0], lon=HOME[1], alt=HOME[2] + 20)])))
    assert run(same_frame, 50) == [], "a task started with the failure's stamp took over"


def test_a_gimbal_task_failed_while_the_aircraft_flies_another_task_is_no_breach() -> None:
    """Campaign seed 41, sequence 113: a look-at failed when the pan & tilt was killed, during a goto; the aircraft
    flying on is the goto's doing. Invariant 2 judges the tasks that fly the aircraft."""
    for detail in (f"module pan_tilt exited (-9): {mri.EFFECT_LOST}",
                   mri.module_error_detail("pan_tilt", 1002, "DSP_WRONG_MODE")):
        m = monitor()
        for i in range(61):
            telemetry(m, 20.0 + i / 2, queue=3 if i < 10 else 2, nav_m=200.0 - 2.5 * i)
        book(m, 30.0, goto_task(None, status="running"),
             task(4, "look_at", 12.0, 30.0, task_type="pan_tilt", status="failed", detail=detail))
        assert run(m, 50) == [], detail


def test_a_task_failed_on_the_dsps_own_flight_fault_is_judged_like_a_lost_module() -> None:
    """Campaign seed 23, sequence 54: the RAL failed a survey on the DSP's LOW_BATTERY while it was flown. A flight
    fault (GPS, battery, rotor, sensor) fails the task whatever the aircraft did; another module error does not
    excuse a failure while progressing."""
    low_battery = mri.module_error_detail("path_follower", 1007, "DSP_LOW_BATTERY")
    assert mri.reported_error(low_battery) == 1007
    stopped = monitor()
    for i in range(61):
        telemetry(stopped, 20.0 + i / 2, queue=3 if i < 10 else 2, nav_m=100.0 - 2.5 * min(i, 26))
    book(stopped, 30.0, goto_task(30.0, status="failed", detail=low_battery))
    assert run(stopped, 50) == []
    refused = monitor()  # the DSP refused one of the follower's commands: not a flight fault
    for i in range(21):
        telemetry(refused, 20.0 + i / 2, queue=3 if i < 10 else 2, nav_m=100.0 - 2.5 * i)
    book(refused, 30.0, goto_task(30.0, status="failed",
                                  detail=mri.module_error_detail("path_follower", 1002, "DSP_WRONG_MODE")))
    assert kinds(run(refused, 40)) == ["failed_while_progressing"]


# ---------------------------------------------------------------- 3. the GRI against the truth


def gri(stamp: float, north_m: float, height: float = 10.0, airborne: bool = True,
        errors: list[ErrorEvent] | None = None) -> GriState:
    tel = RobotTelemetry(stamp=stamp, position=GeoPoint(lat=HOME[0] + north_m * M, lon=HOME[1], alt=HOME[2] + height),
                         airborne=airborne)
    return GriState(robot="uav1", stamp=stamp + 0.5, telemetry=tel, errors=errors or [])


def test_the_gri_where_the_truth_is_agrees() -> None:
    m = monitor()
    for i in range(60):
        truth(m, i / 10, north_m=i / 10)
    m.on_gri_state(6.0, gri(5.0, north_m=5.0 + 3.0))
    assert run(m, 10) == [] and m.counts["gri_compared"] == 1


def test_the_gri_may_show_where_the_aircraft_was_up_to_half_a_second_before_its_stamp() -> None:
    """The telemetry module stamps a frame a little after the DSP measured it: at 20 m/s, 0.3 s is 6 m."""
    m = monitor()
    for i in range(60):
        truth(m, i / 10, north_m=20.0 * i / 10)
    m.on_gri_state(6.0, gri(5.0, north_m=20.0 * 4.7))
    assert run(m, 10) == []
    m.on_gri_state(6.0, gri(5.0, north_m=20.0 * 4.0))  # 1 s old: 10 m behind the oldest truth it may be
    assert kinds(run(m, 10)) == ["gri_position"]


def test_the_gri_more_than_5_m_off_the_truth_or_wrong_about_airborne_is_a_breach() -> None:
    m = monitor()
    for i in range(60):
        truth(m, i / 10, north_m=i / 10)
    m.on_gri_state(6.0, gri(5.0, north_m=5.0 + 7.0, airborne=False))
    assert kinds(run(m, 10)) == ["gri_position", "gri_airborne"]


def test_at_a_lift_off_the_gri_may_show_the_height_the_truth_reaches_at_the_end_of_the_stamps_frame() -> None:
    """Campaign seed 7, sequence 43 (1 of 200): in lockstep a frame's telemetry is stamped with the time its frame
    began, and the DSP's airborne flag of the frame's last instant reached the GRI while the truth of that instant,
    stamped a float's rounding after stamp + step_s, was left out of the window ("airborne=True, the truth False").
    The window now reaches as far as the position check's (the clock skew included). A GRI airborne with the truth
    on the ground over all of it is still a breach."""
    m = monitor(stamp_lag_s=0.2)
    for i in range(101):
        truth(m, i / 10, height=0.0)
    truth(m, 10.2 + 1e-9, height=0.25)  # the first instant above 0.2 m, at the end of the frame stamped 10.0
    m.on_gri_state(10.0, gri(10.0, north_m=0.0, height=0.25))
    truth(m, 13.0, height=1.5)
    assert "gri_airborne" not in kinds(run(m, 13))
    late = monitor(stamp_lag_s=0.2)
    for i in range(131):
        truth(late, i / 10, height=0.0)
    late.on_gri_state(12.0, gri(10.0, north_m=0.0, height=0.25))  # airborne, the truth on the ground throughout
    assert kinds(run(late, 13)) == ["gri_airborne"]


def test_a_loss_of_control_reported_within_1_s_is_right() -> None:
    m = monitor()
    truth(m, 10.0)
    truth(m, 10.05, roll=70.0)
    m.on_gri_event(11.0, GriEvent(robot="uav1", stamp=10.8, kind="task_failed", task_id=2, detail="attitude 70 deg"))
    assert run(m, 20) == []


def test_a_loss_of_control_unreported_or_reported_late_is_a_critical_breach() -> None:
    m = monitor()
    truth(m, 10.0, heading=0.0)
    truth(m, 10.05, heading=30.0)  # 600 deg/s: spinning
    m.on_gri_state(12.5, gri(12.0, 0.0, errors=[ErrorEvent(module="ral", code=603, stamp=11.6, detail="late")]))
    m.on_gri_state(12.6, gri(12.1, 0.0, errors=[ErrorEvent(module="safety_monitor", code=903, stamp=10.5)]))
    (b,) = [b for b in run(m, 20) if b.kind == "loss_of_control_unreported"]
    assert b.severity is Severity.CRITICAL and "heading turning" in b.evidence[0]
    assert any("reported later" in line for line in b.evidence)


# ---------------------------------------------------------------- 4. abort within 100 ms


def test_an_abort_acknowledged_within_100_ms_is_right() -> None:
    m = monitor()
    book(m, 10.1, task(4, "abort", 10.0, 10.02, kind=""))
    sent(m, 10.08, p.Abort())
    assert run(m, 20) == []


@pytest.mark.parametrize(("ack_at", "kind"), [(10.25, "abort_late"), (None, "abort_missing")])
def test_an_abort_late_or_never_is_a_breach(ack_at: float | None, kind: str) -> None:
    m = monitor()
    book(m, 10.1, task(4, "abort", 10.0, 10.02, kind=""))
    if ack_at is not None:
        sent(m, ack_at, p.Abort())
    (b,) = run(m, 20)
    assert (b.invariant, b.kind) == (Invariant.ABORT_LATENCY, kind)
    if ack_at is not None:
        assert "250 ms" in b.summary


# ---------------------------------------------------------------- 5. geofence and clearance


def test_inside_the_fence_and_above_the_clearance_is_right() -> None:
    m = monitor()
    book(m, 0.0, task(1, "take_off", 0.0, 5.0, params=TakeOff(height=10.0)))
    for i in range(50):  # climbs through the clearance during take-off, then holds at 10 m
        truth(m, i / 10, height=min(10.0, i / 2))
    for i in range(50, 100):
        truth(m, i / 10, height=10.0, north_m=(i - 50) * 10)
    assert [b for b in run(m, 10) if b.invariant is Invariant.ENVELOPE] == []


def test_outside_the_fence_for_a_second_is_one_critical_breach() -> None:
    m = monitor()
    for i in range(30):
        truth(m, i / 10, north_m=3000.0 + i)
    (b,) = run(m, 5)
    assert (b.kind, b.severity) == ("outside_geofence", Severity.CRITICAL)
    m2 = monitor()
    for i in range(5):  # out for 0.4 s only: a glitch, not an excursion
        truth(m2, i / 10, north_m=3001.0)
    assert run(m2, 5) == []


def test_hovering_below_the_clearance_with_no_landing_is_a_breach_and_landing_is_not() -> None:
    m = monitor()
    for i in range(30):
        truth(m, i / 10, height=3.0)
    assert kinds(run(m, 5)) == ["below_clearance"]
    m2 = monitor()
    book(m2, 0.0, task(2, "land", 0.0))
    for i in range(30):
        truth(m2, i / 10, height=3.0 - i / 10)
    assert run(m2, 5) == []


def test_without_truth_the_dsp_telemetry_is_the_position() -> None:
    m = monitor()
    telemetry(m, 0.0, height=0.0, airborne=False)  # on the ground: home
    for i in range(1, 30):
        telemetry(m, i / 10, height=3.0)
    assert kinds(run(m, 5)) == ["below_clearance"]


# ---------------------------------------------------------------- helpers


def test_stop_commands_and_distances() -> None:
    assert is_stop(p.Abort()) and is_stop(p.SetSpeed(speed=0.0)) and not is_stop(p.SetSpeed(speed=1.0))
    assert not is_stop(p.SetPanTiltMode(mode=p.PanTiltMode.TARGET))
    assert ground_distance_m(HOME[0], HOME[1], HOME[0] + 100 * M, HOME[1]) == pytest.approx(100.0, rel=1e-6)


def test_a_breach_describes_itself_with_its_evidence() -> None:
    b = Breach(robot="uav1", invariant=Invariant.ENVELOPE, kind="below_clearance", severity=Severity.CRITICAL,
               stamp=1.0, summary="low", evidence=["truth at 1.0", "MIN_CLEARANCE 5"])
    assert b.describe() == "[CRITICAL invariant 5 below_clearance] low\n    truth at 1.0\n    MIN_CLEARANCE 5"


@pytest.mark.parametrize(("tumble_at", "breaches"), [(30.06, []), (31.5, ["failed_while_progressing"])])
def test_a_robot_may_report_its_loss_of_control_just_before_the_truth_shows_it(
        tumble_at: float, breaches: list[str]) -> None:
    """Campaign (the uQuad regression "kill module=ral; motor_loss"): the flight module reports 706 for a motor it
    sees stop, and the RAL failed the goto on it 60 ms before the truth's attitude crossed the threshold. A loss of
    control the truth shows within ``loc_lead_s`` after the failure confirms it; one 1.5 s later does not."""
    m = monitor(dsp_commands=False, gri_airborne_is_motors=True)
    goal = Goto(waypoints=[Waypoint(lat=HOME[0] + 20 * M, lon=HOME[1], alt=HOME[2] + 10)])
    for i in range(201):  # closing on the goal until the motor stops at 30 s, then tumbling where it is
        now = 20.0 + i / 10
        truth(m, now, north_m=min(now, 30.0) - 20.0, roll=70.0 if now >= tumble_at else 0.0)
    book(m, 30.0, task(2, "goto", 20.0, 30.0, status="failed", params=goal,
                       detail="loss of control (robot): the robot reports it lost control (error 706)"))
    assert [k for k in kinds(run(m, 45)) if k in ("failed_while_progressing", "flew_on_after_failure")] == breaches
