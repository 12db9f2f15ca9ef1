"""What the RAL decides about tasks, as pure functions: admission against the robot's .conf limits, and the
judge (completed / failed for lack of progress / running) with an injected clock."""

from __future__ import annotations

import math

import msgspec
import pytest

from bbcs.contracts import gri
from bbcs.contracts import tasks as t
from bbcs.contracts.geo import VelocityNED
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.geodesy import LocalFrame
from ral.tasks import (
    Geofence,
    JudgeConfig,
    Limits,
    Plan,
    Progress,
    Rejected,
    admit,
    after_completed,
    available_kinds,
    distance_m,
    judge,
    limits_conf_errors,
    load_limits,
    next_waypoint,
    path_to_go,
    return_path,
    return_request,
)

AVAILABLE = {
    "take_off": "movement",
    "land": "movement",
    "goto": "movement",
    "follow_path": "movement",
    "hold": "movement",
    "look_at": "pan_tilt",
    "pan_tilt": "pan_tilt",
    "abort": "movement",
    "survey": "movement",
    "orbit": "movement",
}
HOME = GeoPoint(lat=37.41, lon=-6.0, alt=12.0)
LIMITS = Limits(max_speed=8.0, cruise_speed=5.0, min_clearance_m=5.0, max_height_m=120.0,
                geofence=Geofence(37.41, -6.0, 3000.0), takeoff_height_m=10.0)
CFG = JudgeConfig(position_tolerance_m=3.0, altitude_tolerance_m=2.0, settle_s=2.0, stall_s=30.0)


def tel(lat: float = 37.41, lon: float = -6.0, alt: float = 12.0, *, queued: int | None = 0,
        airborne: bool | None = True) -> RobotTelemetry:
    return RobotTelemetry(stamp=0.0, position=GeoPoint(lat=lat, lon=lon, alt=alt), waypoints_queued=queued,
                          airborne=airborne)


def path(n: int = 3, alt: float = 30.0, speed: float | None = None) -> t.Goto:
    return t.Goto(waypoints=[t.Waypoint(lat=37.41 + 0.0001 * i, lon=-6.0, alt=alt) for i in range(1, n + 1)],
                  speed=speed)


def check(request: t.TaskParams, limits: Limits = LIMITS, **kw) -> Plan | Rejected:
    args = dict(available=AVAILABLE, task_names={}, limits=limits, cfg=CFG, telemetry=tel(airborne=True),
                home=HOME)
    args.update(kw)
    return admit(request, **args)  # type: ignore[arg-type]


def test_distance_is_metres() -> None:
    # WGS84: a degree of latitude is 110,574 m at the equator; a degree of longitude 55,800 m at 60° N
    assert distance_m(0.0, 0.0, 0.001, 0.0) == pytest.approx(110.574, abs=0.01)
    assert distance_m(60.0, 0.0, 60.0, 0.002) == pytest.approx(111.60, abs=0.05)


def test_admission_maps_kind_to_manifest_task_and_type() -> None:
    plan = check(t.LookAt(lat=37.41, lon=-6.0, alt=12.0))
    assert isinstance(plan, Plan) and (plan.name, plan.task_type) == ("look_at", "pan_tilt")
    remapped = check(t.Hold(), task_names={"hold": "abort"})
    assert isinstance(remapped, Plan) and remapped.name == "abort"


def test_a_task_the_robot_lacks_is_rejected_with_what_it_offers() -> None:
    r = check(t.Track())
    assert isinstance(r, Rejected) and "no task 'track'" in r.reason and "goto" in r.reason
    assert "abort" not in r.reason, "abort is not a task a station sends as a task"
    assert isinstance(check(t.Hold(), available={}), Rejected)


def test_available_lists_only_what_a_ground_station_can_send() -> None:
    kinds = available_kinds({**AVAILABLE, "bridge": "movement", "custom": "movement"}, {})
    assert "abort" not in kinds and "custom" not in kinds and kinds["bridge"] == "movement"


def test_no_speed_flies_at_the_cruise_speed_and_without_one_is_refused() -> None:
    plan = check(path())
    assert isinstance(plan, Plan) and plan.params.speed == 5.0  # type: ignore[union-attr]
    r = check(path(), limits=Limits(max_speed=8.0))
    assert isinstance(r, Rejected) and "CRUISE_SPEED" in r.reason


def test_speed_above_max_speed_is_refused() -> None:  # issue 11 case 5
    r = check(path(speed=12.0))
    assert isinstance(r, Rejected) and "12 m/s is above MAX_SPEED 8 m/s" in r.reason
    assert isinstance(check(path(speed=8.0)), Plan)


def test_waypoint_below_the_clearance_above_home_is_refused() -> None:  # issue 11 case 7
    r = check(path(alt=5.0))
    assert isinstance(r, Rejected)
    assert "5 m above sea level" in r.reason and "minimum clearance is 5 m" in r.reason
    assert isinstance(check(path(alt=17.0)), Plan)
    assert isinstance(check(path(alt=133.0)), Rejected), "above the ceiling"


def test_clearance_needs_a_known_ground_reference() -> None:
    r = check(path(), home=None)
    assert isinstance(r, Rejected) and "take-off point" in r.reason


def test_waypoint_outside_the_geofence_is_refused() -> None:
    far = t.Goto(waypoints=[t.Waypoint(lat=37.41 + 0.04, lon=-6.0, alt=30.0)])
    r = check(far)
    assert isinstance(r, Rejected) and "outside the geofence" in r.reason


def test_take_off_to_a_height_the_dsp_cannot_honour_is_refused() -> None:  # issue 11 case 4
    r = check(t.TakeOff(height=20.0))
    assert isinstance(r, Rejected) and "fixed take-off height 10 m" in r.reason
    assert isinstance(check(t.TakeOff(height=10.0)), Plan)


def test_uav1_conf_limits() -> None:
    from pathlib import Path

    limits = load_limits(str(Path(__file__).resolve().parents[2] / "bbcs_conf" / "uav1.conf"))
    assert limits.max_speed == 8.0 and limits.cruise_speed == 5.0 and limits.takeoff_height_m == 10.0
    assert limits.geofence is not None and limits.min_clearance_m == 5.0
    assert limits.return_height_m == 10.0 and limits.return_action == "land"


def running(request: t.TaskParams, started: float = 0.0) -> t.TaskInfo:
    return t.TaskInfo(id=1, name=t.kind_of(request), task_type="movement", kind=t.kind_of(request),
                      params=request, started=started)


def run(task: t.TaskInfo, steps: list[tuple[float, RobotTelemetry]], start: float = 0.0) -> list[str]:
    progress = Progress(started=start)
    out = []
    for now, telemetry in steps:
        v = judge(task, progress, telemetry, HOME, LIMITS, CFG, now)
        progress = v.progress
        out.append(v.status)
    return out


def test_goto_completes_when_queue_empty_and_at_last_waypoint() -> None:
    task = path(3)
    last = task.waypoints[-1]
    assert run(running(task), [
        (0.1, tel(alt=12.0, queued=0)),
        (0.5, tel(alt=30.0, queued=3)),
        (5.0, tel(last.lat, last.lon, 30.0, queued=1)),
        (5.5, tel(last.lat, last.lon, 35.0, queued=0)),
        (6.0, tel(last.lat + 0.00001, last.lon, 31.0, queued=0)),
    ]) == ["running"] * 4 + ["completed"]


def test_goto_at_last_waypoint_before_the_path_arrives_waits_to_settle() -> None:
    task = t.Goto(waypoints=[t.Waypoint(lat=37.41, lon=-6.0, alt=12.0)])
    assert run(running(task, 10.0), [(10.5, tel()), (12.0, tel())], start=10.0) == ["running", "completed"]


def test_an_onboard_path_completes_only_once_the_aircraft_has_stopped_at_its_end() -> None:
    """Campaign seed 7, sequence 111: mode 3 has no DSP queue, so "near the end" alone completed the task while
    the onboard follower still flew the last metres, and its references reached the DSP after the task ended."""
    task = t.FollowPath(waypoints=path(3).waypoints)
    last = task.waypoints[-1]

    def moving(speed: float) -> RobotTelemetry:
        return msgspec.structs.replace(tel(last.lat - 0.00002, last.lon, 30.0, queued=0),
                                       velocity=VelocityNED(vn=speed, ve=0.0, vd=0.0))

    assert run(running(task), [(3.0, moving(3.0)), (4.0, moving(1.5)), (5.0, moving(0.4))]) == [
        "running", "running", "completed"]


def test_an_onboard_path_is_judged_by_where_the_aircraft_is_whatever_the_dsps_queue_still_holds() -> None:
    """Campaign seed 23, sequence 13: a mode-3 path started while the DSP's queue still held the mode-1 path
    before it (3 waypoints). Taken as this path's queue, it pinned the judge to the first waypoint, so once the
    aircraft flew past it every metre flown counted as a metre lost, and the task failed while the aircraft
    flew it ("no progress for 31 s"). The same stale queue under the DSP's own follower is still believed."""
    waypoints = [t.Waypoint(lat=37.4100 + 0.0004 * i, lon=-6.0, alt=30.0) for i in range(3)]
    steps = [(float(s), tel(lat=37.4096 + 0.00001 * s, alt=30.0, queued=3)) for s in range(0, 95, 5)]
    assert set(run(running(t.FollowPath(waypoints=waypoints, follower="onboard")), steps)) == {"running"}
    assert "failed" in run(running(t.FollowPath(waypoints=waypoints)), steps)


def test_a_path_that_makes_no_progress_fails_after_stall_s() -> None:  # issue 11 cases 3 and 6
    task = path(3)
    still = tel(alt=30.0, queued=3)
    statuses = run(running(task), [(float(s), still) for s in range(0, 31, 5)])
    assert statuses[:-1] == ["running"] * 6 and statuses[-1] == "failed"


def test_progress_keeps_a_path_running() -> None:
    task = path(3)
    steps = [(float(s), tel(lat=37.409 + 0.00001 * s, alt=30.0, queued=3)) for s in range(0, 60, 5)]
    assert set(run(running(task), steps)) == {"running"}


def test_take_off_completes_at_the_dsp_take_off_height_above_home() -> None:
    task = running(t.TakeOff(height=10.0))
    assert run(task, [(1.0, tel(alt=12.0, airborne=False)), (2.0, tel(alt=15.0)), (3.0, tel(alt=20.5))]) == [
        "running", "running", "completed"]


def test_land_completes_on_touchdown() -> None:
    task = running(t.Land())
    assert run(task, [(1.0, tel(alt=25.0)), (3.0, tel(alt=12.0, airborne=False))]) == ["running", "completed"]


def test_continuous_tasks_never_complete_or_stall() -> None:
    for request in (t.Hold(), t.SetPanTilt(pan=0.0, tilt=0.0), t.Track()):
        assert set(run(running(request), [(float(s), tel()) for s in range(0, 100, 10)])) == {"running"}


@pytest.mark.parametrize(
    "payload",
    [
        {"type": "goto", "waypoints": [{"lat": 91.0, "lon": 0.0, "alt": 10.0}]},
        {"type": "goto", "waypoints": []},
        {"type": "pan_tilt", "pan": 0.0, "tilt": 95.0},
        {"type": "take_off", "height": 0.0},
        {"type": "teleport"},
        {"pan": 1.0},
    ],
)
def test_bad_requests_fail_at_decoding(payload: dict) -> None:
    with pytest.raises(msgspec.ValidationError):
        gri.decode_request(msgspec.msgpack.encode(payload))


def test_requests_round_trip_with_every_kind() -> None:
    requests = [path(2), gri.Abort(), gri.Cancel(task_type="pan_tilt"), t.TakeOff(height=5.0),
                t.FollowPath(waypoints=path(1).waypoints, heading=1.0), t.FollowVisionPath(speed=3.0),
                t.Bridge(ref_altitude=30.0), gri.RestartModule(module="dsp")]
    for request in requests:
        assert gri.decode_request(gri.encode(request)) == request


SQUARE = [t.Vertex(lat=37.41 + dlat, lon=-6.0 + dlon) for dlat, dlon in ((0, 0), (0, 0.001), (0.001, 0.001),
                                                                          (0.001, 0))]


def test_survey_and_orbit_are_admitted_at_the_cruise_speed_within_the_limits() -> None:
    plan = check(t.Survey(polygon=SQUARE, height=40.0))
    assert isinstance(plan, Plan) and plan.name == "survey" and plan.params.speed == 5.0  # type: ignore[union-attr]
    assert isinstance(check(t.Orbit(lat=37.41, lon=-6.0, radius=100.0, speed=6.0)), Plan)
    fast = check(t.Orbit(lat=37.41, lon=-6.0, radius=100.0, speed=9.0))
    assert isinstance(fast, Rejected) and "above MAX_SPEED 8" in fast.reason
    low = check(t.Survey(polygon=SQUARE, height=3.0))
    assert isinstance(low, Rejected) and "minimum clearance 5 m" in low.reason
    high = check(t.Orbit(lat=37.41, lon=-6.0, radius=100.0, height=150.0))
    assert isinstance(high, Rejected) and "ceiling 120 m" in high.reason


def test_an_orbit_reaching_out_of_the_geofence_is_refused() -> None:
    r = check(t.Orbit(lat=37.41 + 0.025, lon=-6.0, radius=300.0))  # centre 2.8 km out, circle to 3.1 km
    assert isinstance(r, Rejected) and "outside the geofence" in r.reason
    far = check(t.Survey(polygon=[*SQUARE[:3], t.Vertex(lat=37.41 + 0.04, lon=-6.0)], height=40.0))
    assert isinstance(far, Rejected) and "polygon vertex 3" in far.reason


def test_a_survey_completes_at_the_generated_paths_last_waypoint_only() -> None:
    task = running(t.Survey(polygon=SQUARE, height=40.0, speed=5.0))
    end = t.Waypoint(lat=37.411, lon=-6.0, alt=52.0)
    at_end = tel(end.lat, end.lon, 52.0, queued=0)
    v = judge(task, Progress(started=0.0), at_end, HOME, LIMITS, CFG, 5.0)
    assert v.status == "running", "no generated path yet: nothing to complete"
    generated = [t.Waypoint(lat=37.41, lon=-6.0, alt=52.0), end]
    v = judge(task, Progress(started=0.0), tel(37.41, -6.0, 52.0, queued=0), HOME, LIMITS, CFG, 5.0,
              generated=generated)
    assert v.status == "running", "not at the generated path's end"
    v = judge(task, v.progress, at_end, HOME, LIMITS, CFG, 6.0, generated=generated)
    assert v.status == "completed"


# ---------------------------------------------------------------- progress along the path (issue 30, case 2)

def at(north: float, east: float, alt: float = 32.0) -> t.Waypoint:
    """A point ``north``/``east`` metres from HOME, ``alt`` m above sea level (the project's geodesy)."""
    lat, lon, _ = LocalFrame(HOME.lat, HOME.lon).to_geo(east, north)
    return t.Waypoint(lat=lat, lon=lon, alt=alt)


def fly(path: list[t.Waypoint], speed: float, start: t.Waypoint, *, queue: bool = True, dt: float = 1.0,
        t0: float = 0.0, load_s: float = 0.0) -> list[tuple[float, RobotTelemetry]]:
    """Telemetry of a robot flying ``path`` from ``start`` at ``speed`` (straight legs, every ``dt`` s), its queue
    holding the waypoints still to reach (``queue=False``: an onboard follower, the DSP queue always empty). For
    ``load_s`` first it hovers at ``start`` while the queue fills one waypoint a second."""
    out = []
    now = t0
    for k in range(int(load_s)):
        out.append((now, tel(start.lat, start.lon, start.alt, queued=min(k, len(path)) if queue else 0)))
        now += dt
    here = (0.0, 0.0, start.alt)
    ref = LocalFrame(start.lat, start.lon)

    def local(w: t.Waypoint) -> tuple[float, float, float]:
        e, n, _ = ref.to_local(w.lat, w.lon)
        return n, e, w.alt

    for i, w in enumerate(path):
        goal = local(w)
        while True:
            d = [g - h for g, h in zip(goal, here, strict=True)]
            dist = math.sqrt(sum(x * x for x in d))
            step = speed * dt
            here = goal if dist <= step else tuple(h + x * step / dist for h, x in zip(here, d, strict=True))
            now += dt
            left = len(path) - i - (1 if here == goal else 0)
            lat, lon, _ = ref.to_geo(here[1], here[0])
            out.append((now, tel(lat, lon, here[2], queued=left if queue else 0)))
            if here == goal:
                break
    return out


def judged(task: t.TaskInfo, steps: list[tuple[float, RobotTelemetry]], generated=None,  # noqa: ANN001
           cfg: JudgeConfig = CFG) -> list[tuple[float, str, str]]:
    """(time, status, detail) of every verdict, up to the first that is not ``running``."""
    progress = Progress(started=steps[0][0])
    out = []
    for now, telemetry in steps:
        v = judge(task, progress, telemetry, HOME, LIMITS, cfg, now, generated=generated)
        progress = v.progress
        out.append((now, v.status, v.detail))
        if v.status != "running":
            break
    return out


def lawnmower(lines: int, length: float, spacing: float, alt: float = 42.0) -> list[t.Waypoint]:
    """A survey-like path: ``lines`` parallel lines ``length`` m long, ``spacing`` m apart, flown back and forth."""
    out = []
    for k in range(lines):
        ends = (0.0, length) if k % 2 == 0 else (length, 0.0)
        out += [at(ends[0], k * spacing, alt), at(ends[1], k * spacing, alt)]
    return out


def test_a_four_waypoint_goto_111_m_apart_completes_at_cruise_speed() -> None:
    """The issue's case: hovering at home, 4 waypoints 111 m apart, 20 m above home, at 5 m/s; the old judge
    (distance to the last waypoint + 50 m per queued one) failed it at +30 s with 3 waypoints queued."""
    hover = at(0.0, 0.0, HOME.alt + 10.0)
    square = [at(111.0, 0.0), at(111.0, 111.0), at(0.0, 111.0), at(0.0, 0.0)]
    verdicts = judged(running(t.Goto(waypoints=square, speed=5.0)), fly(square, 5.0, hover, load_s=3))
    assert verdicts[-1][1] == "completed", verdicts[-1]
    assert verdicts[-1][0] > 80.0, "the whole square was flown"


def test_a_long_survey_flown_at_cruise_speed_never_stalls() -> None:
    path = lawnmower(lines=12, length=400.0, spacing=25.0)  # ~5 km, ~17 min at 5 m/s
    start = at(-30.0, -30.0, HOME.alt + 10.0)
    task = running(t.Survey(polygon=SQUARE, height=30.0, speed=5.0))
    verdicts = judged(task, fly(path, 5.0, start, load_s=10), generated=path)
    assert [v for v in verdicts if v[1] == "failed"] == []
    assert verdicts[-1][1] == "completed" and verdicts[-1][0] > 900.0


def test_an_orbit_flown_slowly_never_stalls() -> None:
    circle = [at(100.0 * math.cos(a), 100.0 * math.sin(a)) for a in (2 * math.pi * k / 36 for k in range(37))]
    task = running(t.Orbit(lat=HOME.lat, lon=HOME.lon, radius=100.0, speed=1.0))
    verdicts = judged(task, fly(circle, 1.0, at(0.0, 0.0, HOME.alt + 10.0)), generated=circle)
    assert verdicts[-1][1] == "completed", verdicts[-1]


def test_the_onboard_follower_with_an_empty_dsp_queue_is_judged_by_the_legs_it_passed() -> None:
    path = lawnmower(lines=6, length=300.0, spacing=30.0)
    task = running(t.FollowPath(waypoints=path, speed=5.0, follower="onboard"))
    verdicts = judged(task, fly(path, 5.0, at(0.0, -20.0, 42.0), queue=False))
    assert verdicts[-1][1] == "completed", verdicts[-1]


def test_a_hovering_aircraft_fails_after_stall_s_and_not_before() -> None:
    square = [at(111.0, 0.0), at(111.0, 111.0), at(0.0, 111.0), at(0.0, 0.0)]
    hover = at(0.0, 0.0, HOME.alt + 10.0)
    still = [(float(s), tel(hover.lat, hover.lon, hover.alt, queued=4)) for s in range(0, 40)]
    verdicts = judged(running(t.Goto(waypoints=square)), still)
    assert verdicts[-1][1] == "failed" and verdicts[-1][0] == 30.0, verdicts[-1]
    assert "no progress for 30 s" in verdicts[-1][2]


def test_an_aircraft_that_stops_half_way_fails_stall_s_after_it_stopped() -> None:
    path = lawnmower(lines=4, length=200.0, spacing=25.0)
    flown = fly(path, 5.0, at(0.0, -10.0, 42.0))[:100]  # 100 s of flight, then it hovers there
    stop_t, last = flown[-1]
    hover = [(stop_t + s, last) for s in range(1, 60)]
    verdicts = judged(running(t.Goto(waypoints=path)), flown + hover)
    assert verdicts[-1][1] == "failed"
    assert stop_t + 29.0 <= verdicts[-1][0] <= stop_t + 31.0, (stop_t, verdicts[-1])


def test_the_waypoint_flown_to_comes_from_the_queue_or_from_the_legs() -> None:
    path = [at(100.0, 0.0), at(100.0, 100.0), at(0.0, 100.0)]
    origin = GeoPoint(lat=HOME.lat, lon=HOME.lon, alt=32.0)
    mid_second_leg = GeoPoint(lat=at(100.0, 50.0).lat, lon=at(100.0, 50.0).lon, alt=32.0)
    assert next_waypoint(path, mid_second_leg, 2, 0, origin, 3.0) == 1, "the queue says it"
    assert next_waypoint(path, mid_second_leg, 7, 0, origin, 3.0) == 1, "a queue longer than the path: the legs"
    assert next_waypoint(path, mid_second_leg, 0, 0, origin, 3.0) == 1, "an empty queue: the legs"
    assert next_waypoint(path, mid_second_leg, None, 2, origin, 3.0) == 2, "never back along the legs"
    start_between = GeoPoint(lat=at(50.0, 0.0).lat, lon=HOME.lon, alt=32.0)
    assert next_waypoint(path, start_between, None, 0, start_between, 3.0) == 0, "on the first leg until reached"
    assert path_to_go(path, mid_second_leg, 1) == pytest.approx(150.0, abs=0.5)
    assert path_to_go(path, origin, 0) == pytest.approx(300.0, abs=0.5)


def test_a_path_still_being_loaded_is_not_progress_nor_a_stall() -> None:
    square = [at(111.0, 0.0), at(111.0, 111.0), at(0.0, 111.0), at(0.0, 0.0)]
    hover = at(0.0, 0.0, 32.0)
    loading = [(float(s), tel(hover.lat, hover.lon, 32.0, queued=q)) for s, q in enumerate((0, 1, 2, 3, 4))]
    verdicts = judged(running(t.Goto(waypoints=square)), loading + [(float(s), loading[-1][1]) for s in range(5, 40)])
    assert verdicts[-1][1] == "failed" and verdicts[-1][0] <= 31.0, "a queue filling at a hovering aircraft"
    verdicts = judged(running(t.Goto(waypoints=square)), loading + fly(square, 5.0, hover, t0=5.0))
    assert verdicts[-1][1] == "completed"


# ---------------------------------------------------------------- return (issue 30, case 10)

RTL = Limits(max_speed=8.0, cruise_speed=5.0, min_clearance_m=5.0, max_height_m=120.0, return_height_m=30.0)


def test_a_return_climbs_where_it_is_then_flies_home_at_the_return_height() -> None:
    here = GeoPoint(lat=at(200.0, 0.0).lat, lon=HOME.lon, alt=HOME.alt + 10.0)
    path = return_path(here, HOME, RTL, CFG)
    assert [(w.lat, w.lon, w.alt) for w in path] == [(here.lat, here.lon, 42.0), (HOME.lat, HOME.lon, 42.0)]
    high = GeoPoint(lat=here.lat, lon=here.lon, alt=HOME.alt + 80.0)
    assert [w.alt for w in return_path(high, HOME, RTL, CFG)] == [42.0, 42.0], "descends to it as well"
    level = GeoPoint(lat=here.lat, lon=here.lon, alt=HOME.alt + 31.0)
    assert len(return_path(level, HOME, RTL, CFG)) == 1, "already at the return height: straight home"
    above_home = GeoPoint(lat=HOME.lat, lon=HOME.lon, alt=HOME.alt + 10.0)
    assert [(w.lat, w.alt) for w in return_path(above_home, HOME, RTL, CFG)] == [(HOME.lat, 42.0)]
    no_height = Limits(max_speed=8.0, min_clearance_m=5.0)
    assert [w.alt for w in return_path(here, HOME, no_height, CFG)] == [22.0], "no RETURN_HEIGHT: at its height"
    low = GeoPoint(lat=here.lat, lon=here.lon, alt=HOME.alt + 2.0)
    assert return_path(low, HOME, no_height, CFG)[-1].alt == 17.0, "never under the minimum clearance"


def failsafe_goto(waypoints: list[t.Waypoint], origin: t.Origin = "failsafe") -> t.TaskInfo:
    return t.TaskInfo(id=7, name="goto", task_type="movement", kind="goto", params=t.Goto(waypoints=waypoints),
                      origin=origin)


def test_a_completed_return_lands_unless_the_conf_says_hover() -> None:
    home_path = [t.Waypoint(lat=HOME.lat, lon=HOME.lon, alt=42.0)]
    assert after_completed(failsafe_goto(home_path), RTL) == t.Land()
    assert after_completed(failsafe_goto(home_path), Limits(max_speed=8.0, return_action="hover")) is None
    assert after_completed(failsafe_goto(home_path, origin="gcs"), RTL) is None, "an operator's goto: nothing"
    assert after_completed(running(t.Hold()), RTL) is None


def test_the_return_failsafe_needs_an_airborne_robot_and_its_take_off_point() -> None:
    airborne = tel(at(200.0, 0.0).lat, HOME.lon, 22.0, airborne=True)
    plan = return_request(airborne, HOME, RTL, CFG)
    assert isinstance(plan, t.Goto) and [w.alt for w in plan.waypoints] == [42.0, 42.0] and plan.speed is None
    assert return_request(tel(airborne=False), HOME, RTL, CFG) == "the robot is on the ground"
    assert "take-off point is not known" in str(return_request(airborne, None, RTL, CFG))
    assert "not known" in str(return_request(None, HOME, RTL, CFG))
    assert isinstance(check(plan, telemetry=airborne), Plan), "admitted as any goto (cruise speed filled in)"


def test_a_return_is_judged_on_its_path_home() -> None:
    start = at(200.0, 0.0, HOME.alt + 10.0)
    plan = return_request(tel(start.lat, start.lon, start.alt), HOME, RTL, CFG)
    assert isinstance(plan, t.Goto)
    verdicts = judged(failsafe_goto(plan.waypoints), fly(plan.waypoints, 5.0, start))
    assert verdicts[-1][1] == "completed"


def test_return_keys_of_the_conf_are_checked_with_file_and_line(tmp_path) -> None:  # noqa: ANN001
    from bbcs.conf import load_conf

    conf = tmp_path / "r.conf"
    conf.write_text("MAX_SPEED: 8\nMIN_CLEARANCE: 5\nMAX_HEIGHT: 120\nRETURN_HEIGHT: 200\n")
    assert [str(e) for e in limits_conf_errors(load_conf(str(conf)))] == [
        f"{conf}:4:1: RETURN_HEIGHT 200 is above MAX_HEIGHT 120"]
    conf.write_text("MAX_SPEED: 8\nMIN_CLEARANCE: 5\nRETURN_HEIGHT: 2\n")
    assert [str(e) for e in limits_conf_errors(load_conf(str(conf)))] == [
        f"{conf}:3:1: RETURN_HEIGHT 2 is under MIN_CLEARANCE 5"]
    conf.write_text("MAX_SPEED: 8\nRETURN_ACTION: fly\n")
    errors = [str(e) for e in limits_conf_errors(load_conf(str(conf)))]
    assert len(errors) == 1 and errors[0].startswith(f"{conf}:2:1: key 'RETURN_ACTION'") and "'fly'" in errors[0]
    conf.write_text("MAX_SPEED: 8\nRETURN_ACTION: hover\n")
    assert load_limits(str(conf)).return_action == "hover" and load_limits(str(conf)).return_height_m is None


# ---------------------------------------------------------------- pan & tilt angles sent again


def gimbal(pan: float | None, tilt: float | None) -> RobotTelemetry:
    return RobotTelemetry(stamp=0.0, pan_deg=pan, tilt_deg=tilt)


def test_pan_tilt_angles_are_sent_again_only_until_the_gimbal_is_seen_there():
    from ral.tasks import PT_RESEND_S, pan_tilt_check

    req = t.SetPanTilt(pan=33.0, tilt=-21.0)
    away = gimbal(0.0, 0.0)
    assert pan_tilt_check(req, away, sent_at=10.0, now=10.0 + PT_RESEND_S - 0.01) == "wait", "give it time first"
    assert pan_tilt_check(req, away, sent_at=10.0, now=10.0 + PT_RESEND_S) == "resend"
    assert pan_tilt_check(req, gimbal(33.5, -20.0), 10.0, 10.1) == "there", "within the tolerance, at once"
    assert pan_tilt_check(req, gimbal(33.0, -25.0), 10.0, 20.0) == "resend", "the tilt alone away"
    wrap = t.SetPanTilt(pan=179.5, tilt=0.0)
    assert pan_tilt_check(wrap, gimbal(-179.5, 0.0), 10.0, 20.0) == "there", "1 degree apart across ±180"
    assert pan_tilt_check(req, gimbal(None, None), 10.0, 20.0) == "wait", "no gimbal telemetry: nothing to compare"
    assert pan_tilt_check(req, None, 10.0, 20.0) == "wait"
    assert pan_tilt_check(t.LookAt(lat=37.4, lon=-6.0, alt=0.0), away, 10.0, 20.0) == "wait", "angles tasks only"


def test_a_path_task_on_the_ground_is_refused_take_off_first() -> None:
    """The campaign's finding: a goto or an orbit sent to a robot on the ground was flown from there, the DSP climbing
    along the path through the minimum clearance with no take-off behind it. Every task that flies the robot
    somewhere now needs it in the air; take-off, landing, hold and the gimbal do not."""
    ground = tel(airborne=False)
    flying = [path(), t.FollowPath(waypoints=path().waypoints), t.Orbit(lat=37.41, lon=-6.0, radius=40.0,
                                                                        height=20.0)]
    for request in flying:
        why = check(request, telemetry=ground)
        assert isinstance(why, Rejected) and why.reason == f"{t.kind_of(request)}: the robot is on the ground " \
            "(take off first)", (request, why)
        assert isinstance(check(request), Plan), request  # the same in the air
    for request in (t.TakeOff(), t.Land(), t.Hold(), t.SetPanTilt(pan=10.0, tilt=-10.0)):
        assert isinstance(check(request, telemetry=ground), Plan), request
    assert isinstance(check(path(), telemetry=tel(airborne=None)), Plan), "airborne unknown: not refused for it"
