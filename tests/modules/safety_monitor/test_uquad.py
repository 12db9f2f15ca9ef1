"""The monitor on a uQuad (no DSP; the truth from the uQuad simulator's stream): a truth line as the monitor's
``VehicleTruth``, which invariants apply, and invariants 2, 3 and 5 judged from that truth, each both ways."""

from __future__ import annotations

import json
import math

import pytest

from bbcs.contracts.gri import GriEvent, GriState
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.contracts.safety import Invariant
from bbcs.contracts.tasks import Goto, TakeOff, Waypoint
from bbcs.geodesy import LocalFrame
from modules.safety_monitor.logic import VEHICLES, MonitorConfig, SafetyMonitor, ground_distance_m, judged_invariants
from modules.safety_monitor.uquad_truth import BadTruthLine, aerospace_attitude, truth_from_bytes, truth_from_line

from .test_logic import book, kinds, run, task

HOME = (-34.918, -56.166, 30.0)  # bbcs_conf/uquad1.conf
FRAME = LocalFrame(*HOME)


def line(t: float, east: float = 0.0, north: float = 0.0, up: float = 0.0, *, roll: float = 0.0,
         pitch: float = 0.0, yaw: float = 0.0, v: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> dict:
    """A truth line as modules/uquad/sim/server.py writes it (radians, east-north-up)."""
    return {"t": t, "stamp": 1000.0 + t, "x": [east, north, up, roll, pitch, yaw, *v, 0.0, 0.0, 0.0],
            "on_ground": up <= 0.0, "w": [0.0] * 4, "motor_efficiency": [1.0] * 4}


def uquad(**kw: object) -> SafetyMonitor:
    return SafetyMonitor(MonitorConfig(robot="uquad1", min_clearance_m=1.0, goal_tolerance_m=3.0,
                                       **VEHICLES["uquad"], **kw))  # type: ignore[arg-type]


def feed(m: SafetyMonitor, t: float, **kw: object) -> None:
    m.on_truth(t, truth_from_line(line(t, **kw), HOME, int(t * 20)))  # type: ignore[arg-type]


def geo(east: float, north: float, up: float) -> Waypoint:
    lat, lon, alt = FRAME.to_geo(east, north, up)
    return Waypoint(lat=lat, lon=lon, alt=alt)


# ---------------------------------------------------------------- the truth line


def test_a_truth_line_is_the_vehicle_truth_at_the_simulators_time() -> None:
    tr = truth_from_line(line(12.35, east=3.0, north=4.0, up=2.5, v=(1.0, 2.0, -0.5)), HOME, 7)
    assert (tr.seq, tr.time_s, tr.home) == (7, 12.35, HOME)
    assert ground_distance_m(tr.lat, tr.lon, HOME[0], HOME[1]) == pytest.approx(5.0, abs=0.01)
    assert FRAME.to_local(tr.lat, tr.lon, tr.alt) == pytest.approx((3.0, 4.0, 2.5), abs=1e-3)
    assert tr.alt - tr.home[2] == pytest.approx(2.5)
    assert tr.vel_neu == (2.0, 1.0, -0.5)  # north, east, up from the model's east, north, up


def test_the_models_angles_become_roll_pitch_and_heading() -> None:
    assert aerospace_attitude(0.0, 0.0, 0.0) == pytest.approx((0.0, 0.0, 90.0))  # yaw 0: facing east
    assert aerospace_attitude(0.0, 0.0, math.pi / 2) == pytest.approx((0.0, 0.0, 0.0))  # facing north
    roll, pitch, _ = aerospace_attitude(math.radians(70.0), math.radians(-20.0), 0.0)
    assert (roll, pitch) == pytest.approx((70.0, 20.0))
    # tumbled past 90 degrees of pitch: the same attitude, pitch within +-90, roll and heading turned round
    roll, pitch, heading = aerospace_attitude(0.0, math.radians(-120.0), 0.0)
    assert (abs(roll), pitch, heading) == pytest.approx((180.0, 60.0, -90.0))


@pytest.mark.parametrize("raw", [b"", b"{\"t\": 1.0, \"x\": [0, 0", b"[1, 2]", b'{"t": 1.0}',
                                 json.dumps({"t": 1.0, "x": [0.0] * 11}).encode(),
                                 json.dumps({"t": 1.0, "x": [float("nan")] * 12}).encode()])
def test_a_cut_or_wrong_line_is_refused(raw: bytes) -> None:
    with pytest.raises(BadTruthLine):
        truth_from_bytes(raw, HOME, 0)


def test_a_raw_line_reads_as_the_decoded_one() -> None:
    doc = line(3.0, east=1.0, up=2.0)
    assert truth_from_bytes(json.dumps(doc).encode(), HOME, 1) == truth_from_line(doc, HOME, 1)


# ---------------------------------------------------------------- which invariants apply


def test_a_robot_without_dsp_commands_is_judged_on_2_3_and_5_with_truth() -> None:
    assert judged_invariants(dsp_commands=True, truth=True) == frozenset(Invariant)
    assert judged_invariants(dsp_commands=True, truth=False) == frozenset(Invariant) - {Invariant.GRI_TRUTH}
    assert judged_invariants(dsp_commands=False, truth=True) == {Invariant.TASK_VERDICT, Invariant.GRI_TRUTH,
                                                                  Invariant.ENVELOPE}
    assert judged_invariants(dsp_commands=False, truth=False) == frozenset()


def test_an_abort_on_a_uquad_is_not_judged_as_a_dsp_abort() -> None:
    """No DSP: no ABORT ever reaches one (the uQuad's abort is its flight module's mode), so invariant 4 is not
    judged; on the UAV the same book is abort_missing (test_logic.py)."""
    m = uquad()
    book(m, 10.1, task(4, "abort", 10.0, 10.02, kind=""))
    assert run(m, 20) == []
    uav = SafetyMonitor(MonitorConfig(robot="uav1"))
    book(uav, 10.1, task(4, "abort", 10.0, 10.02, kind=""))
    assert kinds(run(uav, 20)) == ["abort_missing"]


# ---------------------------------------------------------------- 2. verdicts from the uQuad's truth


def goto(ended: float, status: str = "completed", detail: str = "") -> object:
    return task(3, "goto", 10.0, ended, status=status, params=Goto(waypoints=[geo(6.0, 0.0, 3.0)]), detail=detail)


def test_a_goto_completed_at_its_goal_on_a_uquad_is_right_and_2_m_short_at_3_m_tolerance_too() -> None:
    m = uquad()
    feed(m, 30.0, east=5.9, up=3.1)
    book(m, 30.0, goto(30.0))
    assert run(m, 40) == []
    assert m.counts["verdicts"] == 1


def test_a_goto_completed_metres_from_its_goal_on_a_uquad_is_a_breach() -> None:
    """The UAV's 11 m grid allowance is not applied on a uQuad: 5 m short of a 6 m goto is wrong."""
    m = uquad()
    feed(m, 30.0, east=1.0, up=3.0)
    book(m, 30.0, goto(30.0))
    (b,) = run(m, 40)
    assert (b.invariant, b.kind) == (Invariant.TASK_VERDICT, "completed_away_from_goal")
    assert "5.0 m from its goal" in b.summary


def test_a_take_off_completed_at_its_height_on_a_uquad() -> None:
    m = uquad()
    feed(m, 20.0, up=2.9)
    book(m, 20.0, task(1, "take_off", 10.0, 20.0, params=TakeOff(height=3.0)))
    assert run(m, 30) == []


def test_a_uquad_task_failed_while_the_truth_closes_on_its_goal_is_a_breach() -> None:
    m = uquad()
    for i in range(21):  # 10 s flying east toward the goal at 6 m
        feed(m, 20.0 + i / 2, east=i * 0.25, up=3.0)
    book(m, 30.0, goto(30.0, status="failed", detail="no progress for 10 s"))
    (b,) = run(m, 40)
    assert b.kind == "failed_while_progressing"
    assert any("distance to the goal" in e and "(truth)" in e for e in b.evidence), b.evidence


def test_a_uquad_task_failed_while_hovering_in_place_is_not_a_breach() -> None:
    m = uquad()
    for i in range(21):
        feed(m, 20.0 + i / 2, east=1.0, up=3.0)
    book(m, 30.0, goto(30.0, status="failed", detail="no progress for 10 s"))
    assert run(m, 40) == []


# ---------------------------------------------------------------- 3 and 5 from the uQuad's truth


def test_a_uquad_tumbling_is_a_loss_of_control_the_robot_must_report() -> None:
    """A lost motor: the truth tilts past 60 degrees. Reported by the RAL within 1 s (its 604): right; not: a
    critical breach."""
    told, silent = uquad(), uquad()
    for m in (told, silent):
        for i in range(10):
            feed(m, 20.0 + i / 10, up=3.0, roll=math.radians(10.0 * i))  # 0 .. 90 degrees
    told.on_gri_event(21.0, GriEvent(robot="uquad1", kind="task_failed", task_id=3, stamp=20.9,
                                     detail="loss of control (tilt)"))
    assert run(told, 30) == []
    (b,) = run(silent, 30)
    assert (b.invariant, b.kind) == (Invariant.GRI_TRUTH, "loss_of_control_unreported")


def test_a_uquad_hovering_below_min_clearance_with_no_landing_is_a_breach() -> None:
    m = uquad()
    book(m, 10.0, task(2, "hold", 5.0))
    for i in range(5):
        feed(m, 10.0 + i / 2, up=0.6)
    assert kinds(run(m, 15)) == ["below_clearance"]
    ok = uquad()
    book(ok, 10.0, task(2, "hold", 5.0))
    for i in range(5):
        feed(ok, 10.0 + i / 2, up=3.0)
    assert run(ok, 15) == []


def test_a_uquad_airborne_while_its_motors_ramp_on_the_ground_is_right_and_not_airborne_in_the_air_is_not() -> None:
    """Campaign --robot uquad, its first take-off: the uQuad's ``airborne`` is its motors running (docs/uquad.md
    §5: the planner left idle at the take-off's start, 1.5 s of motor ramp on the ground), so the GRI said
    airborne with the truth on the ground for 2 s, which the UAV's rule (the DSP's flag flips at lift-off) called
    gri_airborne. On a uQuad only airborne=False in the air is wrong; the UAV keeps its rule."""
    def on_ground_then(m: SafetyMonitor, airborne: bool, height: float) -> list[str]:
        for i in range(60):
            feed(m, i / 10, up=height)
        m.on_gri_state(6.0, GriState(robot="uquad1", stamp=5.5, telemetry=RobotTelemetry(
            stamp=5.0, position=GeoPoint(lat=HOME[0], lon=HOME[1], alt=HOME[2] + height), airborne=airborne)))
        return kinds(run(m, 10))

    assert on_ground_then(uquad(), airborne=True, height=0.0) == []
    assert on_ground_then(uquad(), airborne=False, height=3.0) == ["gri_airborne"]
    assert on_ground_then(uquad(), airborne=False, height=0.0) == []
    uav = SafetyMonitor(MonitorConfig(robot="uav1"))
    assert on_ground_then(uav, airborne=True, height=0.0) == ["gri_airborne"]


def test_a_uquad_that_tumbles_cuts_its_motors_in_the_air_and_its_failed_goto_is_no_breach() -> None:
    """Campaign --robot uquad, 'take_off h=3; done s=90; goto to=4:0 h=3 v=2; wait s=2; motor_loss motor=1; wait
    s=20': the goto, closing on its goal, fails on the flight module's tumble cut (706) and the GRI says airborne=
    False (motors off) while the quadrotor still falls from 3 m. Both are the failsafe the robot must run, not
    breaches, when the truth shows the loss of control; without it, the same GRI and the same failure are."""
    def flight(tumbles: bool) -> list[str]:
        m = uquad()
        for i in range(40):  # 4 s closing on the goal 6 m east, then (tumbles) rolled past 60 degrees
            t = 16.0 + i / 10
            feed(m, t, east=min(i * 0.1, 5.0), up=3.0, roll=math.radians(80.0) if tumbles and t >= 19.5 else 0.0)
        m.on_gri_event(19.8, GriEvent(robot="uquad1", kind="task_failed", task_id=3, stamp=19.7,
                                      detail="module uquad reported error 706 LOSS_OF_CONTROL"))
        m.on_gri_state(20.0, GriState(robot="uquad1", stamp=19.9, telemetry=RobotTelemetry(
            stamp=19.8, position=GeoPoint(lat=FRAME.to_geo(3.9, 0.0, 3.0)[0], lon=FRAME.to_geo(3.9, 0.0, 3.0)[1],
                                          alt=HOME[2] + 3.0), airborne=False)))
        for i in range(20):
            feed(m, 20.0 + i, east=4.0, up=0.0)
        book(m, 40.0, goto(19.7, status="failed", detail="module uquad reported error 706 LOSS_OF_CONTROL"))
        return kinds(run(m, 60))

    assert flight(tumbles=True) == []
    assert sorted(flight(tumbles=False)) == ["failed_while_progressing", "gri_airborne"]
