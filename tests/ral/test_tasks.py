"""Task admission, one task per type, cancel/abort, and completion detected from telemetry."""

from __future__ import annotations

import msgspec
import pytest

from bbcs.robot import GeoPoint, RobotTelemetry
from bbcs.contracts import gri
from ral.tasks import Plan, QueueConfig, Rejected, TaskQueue, distance_m

AVAILABLE = {
    "take_off": "movement",
    "land": "movement",
    "goto": "movement",
    "hold": "movement",
    "look_at": "pan_tilt",
    "pan_tilt": "pan_tilt",
    "abort": "movement",
}
HOME = GeoPoint(lat=37.41, lon=-6.0, alt=10.0)


def tel(
    lat: float = 37.41,
    lon: float = -6.0,
    alt: float = 10.0,
    *,
    queued: int | None = 0,
    airborne: bool | None = True,
) -> RobotTelemetry:
    return RobotTelemetry(
        stamp=0.0, position=GeoPoint(lat=lat, lon=lon, alt=alt), waypoints_queued=queued, airborne=airborne
    )


def queue(**cfg: float) -> TaskQueue:
    q = TaskQueue("uav1", QueueConfig(**cfg), available=dict(AVAILABLE))
    q.on_telemetry(tel(airborne=False), 0.0)
    return q


def path(n: int = 3) -> gri.Goto:
    return gri.Goto(
        waypoints=[gri.Waypoint(lat=37.41 + 0.0001 * i, lon=-6.0, alt=30.0) for i in range(1, n + 1)]
    )


def start(q: TaskQueue, task: gri.Task, now: float = 0.0) -> gri.TaskInfo:
    plan = q.admit(task)
    assert isinstance(plan, Plan), plan
    info, _ = q.start(plan, now)
    return info


def test_distance_is_metres() -> None:
    assert distance_m(0.0, 0.0, 0.001, 0.0) == pytest.approx(111.2, abs=0.2)
    assert distance_m(60.0, 0.0, 60.0, 0.002) == pytest.approx(111.2, abs=0.3)


def test_admission_maps_kind_to_manifest_task_and_type() -> None:
    plan = queue().admit(path(10))
    assert isinstance(plan, Plan)
    assert (plan.kind, plan.name, plan.task_type, plan.params) == (
        "goto",
        "goto",
        "movement",
        {"n_points": "10"},
    )


def test_task_names_can_be_remapped() -> None:
    q = queue()
    q.task_names = {"goto": "follow_dsp"}
    q.available["follow_dsp"] = "movement"
    plan = q.admit(path())
    assert isinstance(plan, Plan) and plan.name == "follow_dsp"


def test_a_task_the_robot_lacks_is_rejected_with_a_reason() -> None:
    result = queue().admit(gri.FollowPath(waypoints=path().waypoints))
    assert isinstance(result, Rejected)
    assert "no task 'follow_path'" in result.reason and "available:" in result.reason


def test_nothing_is_admitted_while_the_task_list_is_unknown() -> None:
    q = TaskQueue("uav1")
    result = q.admit(gri.Hold())
    assert isinstance(result, Rejected) and "Module Manager" in result.reason


def test_far_waypoint_is_rejected() -> None:
    q = queue(max_range_m=1000.0)
    far = gri.Goto(
        waypoints=[gri.Waypoint(lat=37.41, lon=-6.0, alt=20.0), gri.Waypoint(lat=37.5, lon=-6.0, alt=20.0)]
    )
    result = q.admit(far)
    assert isinstance(result, Rejected) and "waypoint 1" in result.reason


def test_one_task_per_type_and_replacement_is_reported() -> None:
    q = queue()
    first = start(q, path())
    look = start(q, gri.LookAt(lat=37.0, lon=-6.0, alt=0.0))
    plan = q.admit(gri.Hold())
    assert isinstance(plan, Plan)
    second, replaced = q.start(plan, 1.0)
    assert replaced is not None and replaced.id == first.id and replaced.status == "replaced"
    assert [t.id for t in q.tasks()] == [second.id, look.id]
    assert second.id > look.id > first.id


def test_cancel_and_abort() -> None:
    q = queue()
    start(q, path())
    start(q, gri.SetPanTilt(pan=10.0, tilt=-20.0))
    cancelled = q.cancel("pan_tilt", 2.0)
    assert cancelled is not None and cancelled.status == "cancelled" and cancelled.ended == 2.0
    assert q.cancel("pan_tilt", 2.0) is None
    start(q, gri.SetPanTilt(pan=0.0, tilt=0.0))
    ended = q.abort(3.0)
    assert sorted(i.task_type for i in ended) == ["movement", "pan_tilt"]
    assert all(i.status == "aborted" for i in ended) and q.tasks() == []


def test_goto_completes_when_queue_empty_and_at_last_waypoint() -> None:
    q = queue(position_tolerance_m=3.0, altitude_tolerance_m=2.0)
    task = path(3)
    info = start(q, task)
    last = task.waypoints[-1]
    assert q.on_telemetry(tel(alt=10.0, queued=0), 0.1) == []  # not there yet
    assert q.on_telemetry(tel(alt=30.0, queued=3), 0.5) == []
    assert q.on_telemetry(tel(last.lat, last.lon, 30.0, queued=1), 5.0) == []  # there, queue not empty
    assert q.on_telemetry(tel(last.lat, last.lon, 35.0, queued=0), 5.5) == []  # too high
    done = q.on_telemetry(tel(last.lat + 0.00001, last.lon, 31.0, queued=0), 6.0)
    assert [(d.id, d.status) for d in done] == [(info.id, "completed")]
    assert q.tasks() == []


def test_goto_at_last_waypoint_before_the_path_arrives_waits_to_settle() -> None:
    q = queue(settle_s=2.0)
    task = gri.Goto(waypoints=[gri.Waypoint(lat=37.41, lon=-6.0, alt=10.0)])
    start(q, task, now=10.0)
    assert q.on_telemetry(tel(queued=0), 10.5) == []
    assert len(q.on_telemetry(tel(queued=0), 12.0)) == 1


def test_take_off_completes_at_height_above_home() -> None:
    q = queue(altitude_tolerance_m=1.0)
    start(q, gri.TakeOff(height=20.0))
    assert q.on_telemetry(tel(alt=10.0, airborne=False), 1.0) == []
    assert q.on_telemetry(tel(alt=25.0), 2.0) == []
    assert len(q.on_telemetry(tel(alt=29.2), 3.0)) == 1


def test_land_completes_on_touchdown() -> None:
    q = queue(settle_s=5.0)
    q.on_telemetry(tel(alt=30.0), 0.0)
    start(q, gri.Land())
    assert q.on_telemetry(tel(alt=15.0), 1.0) == []
    assert len(q.on_telemetry(tel(alt=10.0, airborne=False), 2.0)) == 1


def test_continuous_tasks_never_complete_by_themselves() -> None:
    q = queue()
    start(q, gri.Hold())
    start(q, gri.SetPanTilt(pan=0.0, tilt=0.0))
    for t in range(20):
        assert q.on_telemetry(tel(queued=0), float(t)) == []
    assert len(q.tasks()) == 2


def test_home_follows_the_robot_on_the_ground_only() -> None:
    q = queue()
    q.on_telemetry(tel(lat=37.42, alt=12.0, airborne=False), 0.0)
    q.on_telemetry(tel(lat=37.43, alt=40.0, airborne=True), 1.0)
    assert q.home == GeoPoint(lat=37.42, lon=-6.0, alt=12.0)


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


def test_requests_round_trip() -> None:
    for request in [path(2), gri.Abort(), gri.Cancel(task_type="pan_tilt"), gri.TakeOff(height=5.0)]:
        assert gri.decode_request(gri.encode(request)) == request
