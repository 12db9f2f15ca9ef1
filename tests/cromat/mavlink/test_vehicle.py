"""One vehicle's mission bookkeeping (cromat/mavlink/vehicle.py): progress, pause and continue, download, from GRI
states and task replies given by hand."""

from __future__ import annotations

from bbcs.contracts import gri
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.contracts.tasks import TaskInfo
from cromat.mavlink.commands import Command, Send, map_command
from cromat.mavlink.dialect import Encoder, mav
from cromat.mavlink.plan import Item, plan_of
from cromat.mavlink.vehicle import RobotSpec, Vehicle

ITEMS = [Item(seq=i, frame=mav.MAV_FRAME_GLOBAL_INT, command=mav.MAV_CMD_NAV_WAYPOINT, x=374117000 + 3000 * i,
              y=-60025000, z=27.0) for i in range(4)]
AVAILABLE = {k: "movement" for k in ("take_off", "land", "goto", "follow_path", "hold")}


def vehicle() -> Vehicle:
    v = Vehicle(RobotSpec(name="uav1"), 1, Encoder(1, lambda _frame: None, None))
    v.set_plan(ITEMS, plan_of(ITEMS, 12.0))
    return v


def state(tasks: list[TaskInfo], queued: int) -> gri.GriState:
    tel = RobotTelemetry(stamp=1.0, position=GeoPoint(lat=37.4117, lon=-6.0025, alt=27.0), airborne=True,
                         waypoints_queued=queued)
    return gri.GriState(robot="uav1", kind="uav", stamp=1.0, telemetry=tel, tasks=tasks, available=AVAILABLE,
                        home=GeoPoint(lat=37.4117, lon=-6.0025, alt=12.0))


def follow(task_id: int, request: gri.FollowPath) -> TaskInfo:
    return TaskInfo(id=task_id, name="follow_path", task_type="movement", kind="follow_path", params=request)


def test_a_paused_mission_continues_from_the_waypoint_it_was_flying_to() -> None:
    v = vehicle()
    v.state = state([], queued=0)
    start = map_command(v.context(), Command(mav.MAV_CMD_MISSION_START, (0.0,) * 7))
    assert isinstance(start, Send) and start.role == "mission"
    request = start.request
    assert isinstance(request, gri.FollowPath)
    v.started("mission", 0, gri.TaskReply(accepted=True, task_id=5, task_type="movement"), request)
    v.state = state([follow(5, request)], queued=0)  # not filled yet: at its first waypoint, nothing reached
    assert v.mission_current() == (0, 4, mav.MISSION_STATE_ACTIVE) and v.newly_reached() == []
    v.state = state([follow(5, request)], queued=2)  # two passed
    assert v.mission_current() == (2, 4, mav.MISSION_STATE_ACTIVE) and v.newly_reached() == [0, 1]
    # pause: where it stands is noted as the hold is asked (once the hold runs, the path's queue is gone)
    hold = map_command(v.context(), Command(mav.MAV_CMD_DO_PAUSE_CONTINUE, (0.0,) * 7))
    assert hold == Send(gri.Hold(), "pause")
    v.pause_at()
    v.state = state([TaskInfo(id=6, name="hold", task_type="movement", kind="hold")], queued=0)
    v.started("pause", 0, gri.TaskReply(accepted=True, task_id=6, task_type="movement"), gri.Hold())
    assert v.paused_at == 2 and v.mission_current() == (2, 4, mav.MISSION_STATE_PAUSED)
    cont = map_command(v.context(), Command(mav.MAV_CMD_DO_PAUSE_CONTINUE, (1.0,) + (0.0,) * 6))
    assert isinstance(cont, Send) and cont.offset == 2
    assert cont.request == gri.FollowPath(waypoints=list(v.plan.waypoints[2:]))  # type: ignore[union-attr]
    v.started("mission", 2, gri.TaskReply(accepted=True, task_id=7, task_type="movement"), cont.request)
    v.state = state([follow(7, cont.request)], queued=1)  # type: ignore[arg-type]
    assert v.mission_current()[0] == 3 and v.newly_reached() == [2]
    v.on_event(gri.GriEvent(robot="uav1", stamp=2.0, kind="task_completed", task_id=7))
    v.state = state([], queued=0)
    assert v.mission_current() == (3, 4, mav.MISSION_STATE_COMPLETE) and v.newly_reached() == [3]


def test_a_pause_resent_after_the_hold_runs_keeps_where_the_mission_stood() -> None:
    """MAVSDK resends a command whose ACK is late; a resend that arrives once the first pause was answered (the hold
    running, the mission's queue gone) is a second pause. It used to note the mission's start, and the continue
    re-flew all four waypoints (the MAVSDK test in three clean-clone runs). It keeps the first pause's place."""
    v = vehicle()
    v.state = state([], queued=0)
    start = map_command(v.context(), Command(mav.MAV_CMD_MISSION_START, (0.0,) * 7))
    assert isinstance(start, Send) and isinstance(start.request, gri.FollowPath)
    v.started("mission", 0, gri.TaskReply(accepted=True, task_id=5, task_type="movement"), start.request)
    v.state = state([follow(5, start.request)], queued=3)  # the first waypoint passed
    v.pause_at()
    v.started("pause", 0, gri.TaskReply(accepted=True, task_id=6, task_type="movement"), gri.Hold())
    v.state = state([TaskInfo(id=6, name="hold", task_type="movement", kind="hold")], queued=0)
    assert v.paused_at == 1
    v.pause_at()  # the resend: the hold runs, nothing of the mission is queued any more
    v.started("pause", 0, gri.TaskReply(accepted=True, task_id=7, task_type="movement"), gri.Hold())
    assert v.paused_at == 1 and v.mission_current() == (1, 4, mav.MISSION_STATE_PAUSED)
    cont = map_command(v.context(), Command(mav.MAV_CMD_DO_PAUSE_CONTINUE, (1.0,) + (0.0,) * 6))
    assert isinstance(cont, Send) and cont.offset == 1
    assert cont.request == gri.FollowPath(waypoints=list(v.plan.waypoints[1:]))  # type: ignore[union-attr]


def test_download_is_the_upload_else_the_running_path() -> None:
    v = vehicle()
    assert v.download_items() == ITEMS
    v.set_plan([], None)
    path = gri.Goto(waypoints=[gri.Waypoint(lat=37.42, lon=-6.0, alt=40.0)])
    v.state = state([TaskInfo(id=3, name="goto", task_type="movement", kind="goto", params=path)], queued=1)
    (item,) = v.download_items()
    assert (item.x, item.y, item.z, item.frame) == (374200000, -60000000, 40.0, mav.MAV_FRAME_GLOBAL_INT)
