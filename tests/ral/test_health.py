"""Health from telemetry (ral/health.py): each detector on hand-made telemetry with its own stamps, the episode
rules (once, cleared, one action), the geometry, and the HEALTH group of a robot .conf."""

from __future__ import annotations

import math
import time

import msgspec
import pytest

from bbcs.conf import ConfError, parse_conf
from bbcs.contracts import gri, mri
from bbcs.contracts import tasks as t
from bbcs.contracts.error_codes import LOSS_OF_CONTROL_CODES
from bbcs.contracts.robot import Attitude, GeoPoint, RobotTelemetry
from bbcs.contracts.safety import Severity
from bbcs.geodesy import offset
from bbcs.testing import wait_until
from ral.failsafe import FailsafeAction
from ral.health import (
    HealthConfig,
    HealthMonitor,
    distance_from_task,
    health_conf_errors,
    load_health,
    ral_conf_errors,
    tilt_deg,
)
from tests.ral.test_module import Rig
from tests.ral.test_module import rig as ral_rig  # noqa: F401  (the RAL against the stand-in manager)

HOME = GeoPoint(lat=-34.918, lon=-56.166, alt=30.0)


def at(east: float = 0.0, north: float = 0.0, up: float = 4.0) -> GeoPoint:
    """A point ``east``/``north``/``up`` metres from HOME."""
    lat, lon = offset(HOME.lat, HOME.lon, north, east)  # WGS84, as the RAL judges (bbcs.geodesy)
    return GeoPoint(lat=lat, lon=lon, alt=HOME.alt + up)


def tel(stamp: float, *, pos: GeoPoint | None = None, roll: float = 0.0, pitch: float = 0.0, heading: float = 90.0,
        airborne: bool = True) -> RobotTelemetry:
    return RobotTelemetry(stamp=stamp, position=pos or at(), attitude=Attitude(roll=roll, pitch=pitch, yaw=heading),
                          heading_deg=heading, airborne=airborne)


def goto(task_id: int = 7, *points: GeoPoint) -> t.TaskInfo:
    wps = [t.Waypoint(lat=p.lat, lon=p.lon, alt=p.alt) for p in points or (at(5.0, 0.0),)]
    return t.TaskInfo(id=task_id, name="goto", task_type="movement", kind="goto", params=t.Goto(waypoints=wps))


def task(kind: str, params: t.TaskParams, task_id: int = 8) -> t.TaskInfo:
    return t.TaskInfo(id=task_id, name=kind, task_type="movement", kind=kind, params=params)


def run(mon: HealthMonitor, samples, running=(), home=HOME):
    """Feed samples; the faults with the stamp each came at."""
    out = []
    for s in samples:
        out += mon.update(s, list(running), home)
    return out


# ---------------------------------------------------------------- attitude


def test_attitude_beyond_the_limit_for_tilt_s_is_one_critical_fault_that_lands_and_fails_the_task() -> None:
    mon = HealthMonitor(HealthConfig(max_tilt_deg=45.0, tilt_s=0.2))
    running = [goto()]
    samples = [tel(0.0), tel(0.1, roll=30.0), tel(0.2, roll=53.0), tel(0.3, roll=60.0), tel(0.4, roll=70.0),
               tel(0.5, roll=80.0)]
    faults = run(mon, samples, running)
    assert len(faults) == 1
    f = faults[0]
    assert (f.detector, f.severity, f.stamp) == ("attitude", Severity.CRITICAL, 0.4)  # 53° at 0.2, held 0.2 s
    assert f.action is FailsafeAction.LAND and [i.id for i in f.fail] == [7]
    assert "tilted 70°" in f.detail and "limit 45°" in f.detail


def test_the_robots_own_loss_of_control_code_is_a_critical_fault_at_once_once_per_episode() -> None:
    mon = HealthMonitor(HealthConfig(tilt_s=0.2), loss_codes=LOSS_OF_CONTROL_CODES["uquad"])
    running = [goto()]
    cut = msgspec.structs.replace(tel(0.3, roll=75.0), error_code=706)  # the uQuad's tumble cut, still falling
    faults = run(mon, [tel(0.0), tel(0.1, roll=50.0), cut], running)
    assert [(f.detector, f.severity, f.stamp) for f in faults] == [("robot", Severity.CRITICAL, 0.3)]
    assert "lost control (error 706)" in faults[0].detail and [i.id for i in faults[0].fail] == [7]
    later = [msgspec.structs.replace(tel(0.4 + 0.1 * i, roll=120.0), error_code=706) for i in range(5)]
    # the same episode (the goto failed by the first fault, the failsafe's landing running): the attitude rule's
    # fault follows, with no second action, and does not fail the landing the first one asked for
    landing = msgspec.structs.replace(task("land", t.Land(), task_id=9), origin="failsafe")
    assert [(f.detector, f.action, f.fail) for f in run(mon, later, [landing])] == [("attitude", None, ())]


def test_a_code_is_a_loss_of_control_only_for_the_kind_that_says_so() -> None:
    uav = HealthMonitor(HealthConfig(), loss_codes=LOSS_OF_CONTROL_CODES.get("uav", frozenset()))
    assert run(uav, [msgspec.structs.replace(tel(0.0), error_code=706)], [goto()]) == []
    uquad = HealthMonitor(HealthConfig(), loss_codes=LOSS_OF_CONTROL_CODES["uquad"])
    assert run(uquad, [msgspec.structs.replace(tel(0.0), error_code=701)], [goto()]) == []  # a driver error


def test_attitude_glitch_shorter_than_tilt_s_is_no_fault_and_pitch_counts_too() -> None:
    mon = HealthMonitor(HealthConfig(tilt_s=0.2))
    assert run(mon, [tel(0.0, roll=80.0), tel(0.1), tel(0.2, pitch=-80.0), tel(0.3)]) == []
    faults = run(mon, [tel(1.0, pitch=-50.0), tel(1.25, pitch=-50.0)])
    assert [f.detector for f in faults] == ["attitude"]


def test_upside_down_counts_as_tilted_whatever_the_euler_split() -> None:
    assert tilt_deg(0.0, 0.0) == pytest.approx(0.0)
    assert tilt_deg(180.0, 0.0) == pytest.approx(180.0)
    assert tilt_deg(30.0, 40.0) == pytest.approx(math.degrees(math.acos(math.cos(math.radians(30)) *
                                                                        math.cos(math.radians(40)))))
    assert tilt_deg(-170.0, 5.0) > 165.0


def test_a_fault_is_reported_once_per_episode_and_again_after_clear_s() -> None:
    mon = HealthMonitor(HealthConfig(tilt_s=0.0, clear_s=1.0))
    first = run(mon, [tel(0.0, roll=60.0), tel(0.1, roll=60.0), tel(0.2), tel(0.6, roll=60.0)])
    assert len(first) == 1  # cleared for 0.2 s only: the same episode
    assert run(mon, [tel(0.7), tel(1.8)]) == []  # clear for 1.1 s: episode over
    again = run(mon, [tel(2.0, roll=60.0)])
    assert len(again) == 1


def test_repeated_or_older_telemetry_is_not_judged_twice() -> None:
    mon = HealthMonitor(HealthConfig(tilt_s=0.15))
    sample = tel(1.0, roll=60.0)
    assert run(mon, [sample, sample, sample, tel(0.5, roll=60.0)]) == []  # one sample at 1.0 only
    assert len(run(mon, [tel(1.2, roll=60.0)])) == 1


# ---------------------------------------------------------------- ground contact


def test_ground_contact_while_airborne_after_having_climbed() -> None:
    mon = HealthMonitor(HealthConfig(ground_m=0.3, ground_clear_m=1.0))
    takeoff = task("take_off", t.TakeOff(height=4.5))
    # on the ground with motors on (taking off): no fault before it was ever above 1 m
    assert run(mon, [tel(0.0, pos=at(up=0.0)), tel(0.5, pos=at(up=0.2)), tel(1.0, pos=at(up=0.8))], [takeoff]) == []
    faults = run(mon, [tel(2.0, pos=at(up=2.5)), tel(3.0, pos=at(up=0.6)), tel(3.1, pos=at(up=0.1))], [goto()])
    assert [(f.detector, f.severity, f.stamp) for f in faults] == [("ground", Severity.CRITICAL, 3.1)]
    assert "0.10 m above the take-off point" in faults[0].detail and faults[0].action is FailsafeAction.LAND


def test_no_ground_fault_while_landing_or_when_not_airborne_or_without_home() -> None:
    mon = HealthMonitor()
    land = task("land", t.Land())
    assert run(mon, [tel(0.0, pos=at(up=3.0)), tel(1.0, pos=at(up=0.0))], [land]) == []
    assert run(mon, [tel(2.0, pos=at(up=0.0), airborne=False)]) == []
    mon2 = HealthMonitor()
    assert run(mon2, [tel(0.0, pos=at(up=3.0)), tel(1.0, pos=at(up=0.0))], [goto()], home=None) == []


def test_after_landing_the_ground_rule_disarms_until_it_climbs_again() -> None:
    mon = HealthMonitor()
    assert run(mon, [tel(0.0, pos=at(up=3.0)), tel(1.0, pos=at(up=0.0), airborne=False)]) == []
    # a new take-off: on the ground with the motors running, not yet above ground_clear_m
    assert run(mon, [tel(2.0, pos=at(up=0.1)), tel(2.5, pos=at(up=0.2))], [task("take_off", t.TakeOff())]) == []


# ---------------------------------------------------------------- far from the task's path


def test_off_path_of_a_goto_is_an_error_that_holds_after_off_s() -> None:
    mon = HealthMonitor(HealthConfig(max_off_m=5.0, off_s=2.0))
    square = goto(7, at(4.0, 0.0), at(4.0, 4.0), at(0.0, 4.0), at(0.0, 0.0))
    on_path = [tel(0.0, pos=at(0.0, 0.0)), tel(1.0, pos=at(4.0, 2.0)), tel(2.0, pos=at(2.0, 4.5))]
    assert run(mon, on_path, [square]) == []
    drift = [tel(3.0 + k, pos=at(12.0 + k, 2.0)) for k in range(4)]  # 8 m and more off the square
    faults = run(mon, drift, [square])
    assert [(f.detector, f.severity, f.stamp) for f in faults] == [("off_path", Severity.ERROR, 5.0)]
    assert faults[0].action is FailsafeAction.HOLD and "from where its goto task keeps it" in faults[0].detail


def test_distance_from_task_geometry() -> None:
    start = at(0.0, 0.0, 4.0)
    line = t.Goto(waypoints=[t.Waypoint(lat=p.lat, lon=p.lon, alt=p.alt) for p in (at(10.0, 0.0, 4.0),)])
    assert distance_from_task(line, start, at(5.0, 3.0, 4.0)) == pytest.approx(3.0, abs=0.01)
    assert distance_from_task(line, start, at(13.0, 4.0, 4.0)) == pytest.approx(5.0, abs=0.01)  # past the end
    assert distance_from_task(line, start, at(-6.0, 8.0, 4.0)) == pytest.approx(10.0, abs=0.01)  # behind start
    assert distance_from_task(t.TakeOff(), start, at(3.0, 4.0, 9.0)) == pytest.approx(5.0, abs=0.01)
    assert distance_from_task(t.Hold(), start, at(0.0, 3.0, 8.0)) == pytest.approx(5.0, abs=0.01)
    assert distance_from_task(t.Manual(north=1.0), start, at(50.0, 0.0)) is None


def test_a_task_is_measured_from_where_it_started() -> None:
    mon = HealthMonitor(HealthConfig(max_off_m=5.0, off_s=0.0))
    hold = task("hold", t.Hold())
    assert run(mon, [tel(0.0, pos=at(100.0, 0.0)), tel(1.0, pos=at(102.0, 0.0))], [hold]) == []
    assert [f.detector for f in run(mon, [tel(2.0, pos=at(107.0, 0.0))], [hold])] == ["off_path"]


# ---------------------------------------------------------------- heading spinning


def test_heading_spinning_across_north_is_found_and_a_turn_is_not() -> None:
    mon = HealthMonitor(HealthConfig(max_yaw_rate_dps=120.0, spin_s=1.0))
    turn = [tel(k * 0.2, heading=(350.0 + 12.0 * k) % 360.0) for k in range(11)]  # 60°/s through north
    assert run(mon, turn) == []
    spin = [tel(3.0 + k * 0.1, heading=(90.0 - 30.0 * k) % 360.0) for k in range(12)]  # 300°/s counter-clockwise
    faults = run(mon, spin)
    assert [(f.detector, f.severity) for f in faults] == [("spin", Severity.CRITICAL)]
    assert 3.0 < faults[0].stamp <= 4.0 and "heading turning" in faults[0].detail
    on_ground = HealthMonitor(HealthConfig(max_yaw_rate_dps=120.0, spin_s=1.0))
    turned_by_hand = [tel(k * 0.1, heading=(90.0 - 30.0 * k) % 360.0, airborne=False) for k in range(12)]
    assert run(on_ground, turned_by_hand) == []


def test_a_helicopter_turning_towards_its_next_waypoint_is_not_a_spin_on_the_defaults() -> None:
    """Seen in a goto on the shipped UAV: 132° between two states a second apart while the DSP turned the nose to the
    next waypoint. With the defaults (a full turn in spin_s) half a turn at any rate, sampled at 1 Hz, is no spin."""
    mon = HealthMonitor(HealthConfig())
    jump = [tel(0.0, heading=0.0), tel(1.0, heading=132.0), tel(2.0, heading=180.0), tel(3.0, heading=180.0),
            tel(4.0, heading=180.0)]
    assert run(mon, jump) == []
    spinning = HealthMonitor(HealthConfig())
    faults = run(spinning, [tel(10.0 + k * 0.5, heading=(75.0 * k) % 360.0) for k in range(10)])  # 150°/s
    assert [f.detector for f in faults] == ["spin"] and faults[0].stamp == 13.0


# ---------------------------------------------------------------- episodes and actions


def test_one_action_per_episode_the_tasks_failed_once_and_none_on_the_ground() -> None:
    mon = HealthMonitor(HealthConfig(tilt_s=0.0, max_off_m=5.0, off_s=0.0))
    running = [goto(7, at(5.0, 0.0))]
    faults = run(mon, [tel(0.0, pos=at()), tel(0.1, pos=at(0.0, 20.0), roll=70.0)], running)
    assert sorted(f.detector for f in faults) == ["attitude", "off_path"]
    assert [f.action for f in faults] == [FailsafeAction.LAND, None]
    assert [len(f.fail) for f in faults] == [1, 0]
    quiet = HealthMonitor(HealthConfig(tilt_s=0.0))
    fallen = run(quiet, [tel(0.0, roll=120.0, airborne=False)])
    assert [(f.detector, f.action) for f in fallen] == [("attitude", None)]


def test_action_none_and_disabled() -> None:
    none = HealthMonitor(HealthConfig(tilt_s=0.0, action_critical="none"))
    assert [f.action for f in run(none, [tel(0.0, roll=90.0)])] == [None]
    off = HealthMonitor(HealthConfig(enabled=False))
    assert run(off, [tel(0.0, roll=90.0), tel(1.0, roll=90.0)]) == []


# ---------------------------------------------------------------- the robot's .conf


def test_health_group_of_a_conf(tmp_path) -> None:
    path = tmp_path / "r.conf"
    path.write_text("MAX_SPEED: 4\nHEALTH: limits {\n  max_tilt_deg = 35\n  max_off_m = 5\n  action_error = land\n}\n")
    cfg = load_health(str(path))
    assert (cfg.max_tilt_deg, cfg.max_off_m, cfg.action_error, cfg.tilt_s) == (35.0, 5.0, "land", 0.2)
    path.write_text("MAX_SPEED: 4\n")
    assert load_health(str(path)) == HealthConfig()


def test_health_group_mistakes_name_file_and_line(tmp_path) -> None:
    text = "MAX_SPEED: 4\nHEALTH: limits {\n  max_tilt_deg = -3\n  max_of_m = 5\n  action_critical = cut\n}\n"
    doc = parse_conf(text, "robot.conf")
    errors = health_conf_errors(doc)
    assert [(e.line, "max_tilt_deg" in str(e) or "max_of_m" in str(e) or "action_critical" in str(e))
            for e in errors] == [(3, True), (5, True), (4, True)]
    assert all("robot.conf" in str(e) for e in errors)
    assert len(ral_conf_errors(doc)) == 3
    path = tmp_path / "bad.conf"
    path.write_text("MAX_SPEED: 4\nHEALTH: limits {\n  tilt_s = soon\n}\n")
    with pytest.raises(ConfError, match=r"bad.conf.*3"):
        load_health(str(path))


# ---------------------------------------------------------------- the RAL acting on a fault (real Zenoh, stand-in)


def test_the_ral_reports_fails_the_task_and_lands_on_a_loss_of_control(request: pytest.FixtureRequest) -> None:
    rig: Rig = request.getfixturevalue("ral_rig")
    reply = rig.gcs.send(ROBOT_GOTO.robot, ROBOT_GOTO.task)
    assert reply.accepted, reply.reason
    here = GeoPoint(lat=37.41, lon=-6.0, alt=30.0)
    for k in range(10):  # telemetry every 0.1 s: level, then rolled 60° and more from 1.1 s on
        rig.manager.telemetry(RobotTelemetry(stamp=1.0 + 0.1 * k, position=here, airborne=True, waypoints_queued=1,
                                             attitude=Attitude(roll=5.0 if k == 0 else 60.0 + k, pitch=0.0, yaw=0.0)))
        time.sleep(0.1)
    wait_until(lambda: "failsafe" in rig.kinds(), what="the failsafe event")
    event = next(e for e in rig.events if e.kind == "failsafe")
    assert "loss of control (attitude)" in event.detail and event.detail.endswith(": land")
    wait_until(lambda: any(e.code == 604 for e in rig.states[-1].errors), what="the error in the GRI state")
    error = next(e for e in rig.states[-1].errors if e.code == 604)
    assert (error.module, error.name, error.severity) == ("ral", "LOSS_OF_CONTROL", Severity.CRITICAL)
    wait_until(lambda: any(r.name == "land" and r.origin == "failsafe" for r in rig.manager.set_tasks()),
               what="the landing asked as a failsafe")
    failed = [r for r in rig.manager.end_tasks() if r.status == "failed"]
    assert failed[0] == mri.EndTask(task_type="movement", task_id=reply.task_id, status="failed",
                                    detail=error.detail), "the goto failed with the reason, before the landing"
    failed_event = next(e for e in rig.events if e.kind == "task_failed" and e.task_id == reply.task_id)
    assert "tilted" in failed_event.detail


class _Goto:
    robot = "uav1"
    task = gri.Goto(waypoints=[gri.Waypoint(lat=37.4102, lon=-6.0, alt=30.0)], speed=4.0)


ROBOT_GOTO = _Goto()


def test_the_rals_conf_check_reports_the_health_group() -> None:
    """``cromat conf check`` / ``launch --check`` call ``Ral.conf_errors``: a HEALTH mistake is among them."""
    from ral.module import Ral

    doc = parse_conf("MAX_SPEED: 4\nHEALTH: limits {\n  spin_s = 0\n}\n", "uquad9.conf")
    errors = Ral.conf_errors(doc)
    assert [(e.line, "spin_s" in str(e)) for e in errors] == [(3, True)]
