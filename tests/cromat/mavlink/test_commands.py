"""COMMAND_LONG/INT → GRI requests or refusals (cromat/mavlink/commands.py), pure."""

from __future__ import annotations

import math

import pytest

from bbcs.contracts import gri
from bbcs.contracts.robot import GeoPoint
from cromat.mavlink.commands import Command, Context, Deny, Local, Send, map_command
from cromat.mavlink.dialect import mav
from cromat.mavlink.plan import Plan

NAN = math.nan
HOME = GeoPoint(lat=37.4117, lon=-6.0025, alt=12.0)
HERE = GeoPoint(lat=37.4127, lon=-6.0015, alt=30.0)
UAV = frozenset({"take_off", "land", "goto", "follow_path", "hold", "pan_tilt", "look_at"})
PLAN = Plan(waypoints=tuple(gri.Waypoint(lat=37.4117 + i * 1e-4, lon=-6.0025, alt=27.0) for i in range(4)),
            seqs=(1, 2, 3, 4), speed=None, count=5)


def ctx(**kw: object) -> Context:
    base: dict[str, object] = dict(robot="uav1", kind="uav", available=UAV, home=HOME, position=HERE, airborne=True,
                                   takeoff_height=10.0, max_speed=8.0)
    base.update(kw)
    return Context(**base)  # type: ignore[arg-type]


def cmd(command: int, *params: float, frame: int = mav.MAV_FRAME_GLOBAL) -> Command:
    p = list(params) + [NAN] * (7 - len(params))
    return Command(command, tuple(p), frame)


def test_take_off_height_follows_px4s_rule() -> None:
    # no altitude, or one below home (MAVSDK sends its own 2 m): the robot's take-off height
    assert map_command(ctx(), cmd(mav.MAV_CMD_NAV_TAKEOFF)) == Send(gri.TakeOff(height=10.0))
    assert map_command(ctx(), cmd(mav.MAV_CMD_NAV_TAKEOFF, *[NAN] * 6, 2.0)) == Send(gri.TakeOff(height=10.0))
    # an AMSL altitude above home is a height above home (the RAL refuses one its take-off cannot fly)
    assert map_command(ctx(), cmd(mav.MAV_CMD_NAV_TAKEOFF, *[NAN] * 6, 32.0)) == Send(gri.TakeOff(height=20.0))
    assert map_command(ctx(takeoff_height=None), cmd(mav.MAV_CMD_NAV_TAKEOFF)) == Send(gri.TakeOff())


def test_land_rtl_reposition() -> None:
    assert map_command(ctx(), cmd(mav.MAV_CMD_NAV_LAND)) == Send(gri.Land())
    rtl = map_command(ctx(), cmd(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH))
    assert isinstance(rtl, Send) and rtl.role == "rtl"
    assert rtl.request == gri.Goto(waypoints=[gri.Waypoint(lat=HOME.lat, lon=HOME.lon, alt=30.0)])
    # under the return height (home + 10 m) and far from home: climbs where it is first, then flies home
    low = map_command(ctx(position=GeoPoint(lat=37.4, lon=-6.0, alt=14.0)), cmd(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH))
    assert isinstance(low, Send) and low.request == gri.Goto(waypoints=[  # type: ignore[union-attr]
        gri.Waypoint(lat=37.4, lon=-6.0, alt=22.0), gri.Waypoint(lat=HOME.lat, lon=HOME.lon, alt=22.0)])
    # under it but over home (within 8 m): straight to home at the return height
    near = GeoPoint(lat=HOME.lat + 3e-5, lon=HOME.lon, alt=14.0)
    assert map_command(ctx(position=near), cmd(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)) == Send(
        gri.Goto(waypoints=[gri.Waypoint(lat=HOME.lat, lon=HOME.lon, alt=22.0)]), "rtl")
    # the .conf's RETURN_HEIGHT; above it, home at the height it has (never a descent before home)
    high = map_command(ctx(rtl_height=3.0), cmd(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH))
    assert isinstance(high, Send) and [w.alt for w in high.request.waypoints] == [30.0]  # type: ignore[union-attr]
    assert isinstance(map_command(ctx(home=None), cmd(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)), Deny)
    # COMMAND_INT reposition, altitude relative to home; speed param1
    go = map_command(ctx(), cmd(mav.MAV_CMD_DO_REPOSITION, 3.0, NAN, NAN, NAN, 37.42, -6.0, 20.0,
                                frame=mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT))
    assert go == Send(gri.Goto(waypoints=[gri.Waypoint(lat=37.42, lon=-6.0, alt=32.0)], speed=3.0))
    # NaN position: where it is, at the new altitude (AMSL: COMMAND_LONG's frame)
    up = map_command(ctx(), cmd(mav.MAV_CMD_DO_REPOSITION, -1.0, NAN, NAN, NAN, NAN, NAN, 50.0))
    assert up == Send(gri.Goto(waypoints=[gri.Waypoint(lat=HERE.lat, lon=HERE.lon, alt=50.0)]))


def test_mission_start_pause_continue_current() -> None:
    assert "no mission" in map_command(ctx(), cmd(mav.MAV_CMD_MISSION_START, 0, 0)).reason  # type: ignore[union-attr]
    start = map_command(ctx(plan=PLAN), cmd(mav.MAV_CMD_MISSION_START, 0, 0))
    assert start == Send(gri.FollowPath(waypoints=list(PLAN.waypoints)), "mission", 0)
    from_item = map_command(ctx(plan=PLAN), cmd(mav.MAV_CMD_MISSION_START, 3, 0))
    assert isinstance(from_item, Send) and from_item.offset == 2
    assert map_command(ctx(plan=PLAN, mission_running=True), cmd(mav.MAV_CMD_DO_PAUSE_CONTINUE, 0)) == \
        Send(gri.Hold(), "pause")
    assert isinstance(map_command(ctx(plan=PLAN), cmd(mav.MAV_CMD_DO_PAUSE_CONTINUE, 1)), Deny)
    cont = map_command(ctx(plan=PLAN, paused_at=1), cmd(mav.MAV_CMD_DO_PAUSE_CONTINUE, 1))
    assert isinstance(cont, Send) and cont.offset == 1 and len(cont.request.waypoints) == 3  # type: ignore[union-attr]
    assert map_command(ctx(plan=PLAN), cmd(mav.MAV_CMD_DO_SET_MISSION_CURRENT, 4)) == Local("set_current", (3,))
    jump = map_command(ctx(plan=PLAN, mission_running=True), cmd(mav.MAV_CMD_DO_SET_MISSION_CURRENT, 4))
    assert isinstance(jump, Send) and jump.offset == 3


def test_flight_modes_as_far_as_the_robot_has_them() -> None:
    custom = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_SAFETY_ARMED
    assert map_command(ctx(), cmd(mav.MAV_CMD_DO_SET_MODE, custom, 4, 3)) == Send(gri.Hold())  # AUTO.LOITER
    rtl = map_command(ctx(), cmd(mav.MAV_CMD_DO_SET_MODE, custom, 4, 5))
    assert isinstance(rtl, Send) and rtl.role == "rtl"
    assert map_command(ctx(), cmd(mav.MAV_CMD_DO_SET_MODE, custom, 4, 6)) == Send(gri.Land())
    stab = map_command(ctx(), cmd(mav.MAV_CMD_DO_SET_MODE, custom, 7, 0))
    assert isinstance(stab, Deny) and "no STABILIZED mode" in stab.reason
    arm = map_command(ctx(), cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1))
    assert isinstance(arm, Deny) and "no arm" in arm.reason
    # a kind without the task: refused naming what is missing
    quad = map_command(ctx(kind="uquad", available=frozenset({"take_off", "land", "goto"})),
                       cmd(mav.MAV_CMD_DO_MOUNT_CONTROL, -30, 0, 40))
    assert isinstance(quad, Deny) and "no pan_tilt task" in quad.reason


def test_speed_gimbal_roi_and_what_is_not_mapped() -> None:
    path = (gri.Waypoint(lat=37.42, lon=-6.0, alt=30.0),)
    assert map_command(ctx(running_path=path), cmd(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 6.0)) == \
        Send(gri.Goto(waypoints=list(path), speed=6.0))
    assert map_command(ctx(), cmd(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 6.0)) == Local("speed", (6.0,))
    over = map_command(ctx(), cmd(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 12.0))
    assert isinstance(over, Deny) and "MAX_SPEED 8" in over.reason
    assert map_command(ctx(), cmd(mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, -30, 40)) == \
        Send(gri.SetPanTilt(pan=40.0, tilt=-30.0))
    # NaN keeps the axis where the pan & tilt is
    assert map_command(ctx(), cmd(mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, -30, NAN), (15.0, 0.0)) == \
        Send(gri.SetPanTilt(pan=15.0, tilt=-30.0))
    assert map_command(ctx(), cmd(mav.MAV_CMD_DO_SET_ROI_LOCATION, *[NAN] * 4, 37.41, -6.0, 12.0)) == \
        Send(gri.LookAt(lat=37.41, lon=-6.0, alt=12.0))
    odd = map_command(ctx(), cmd(mav.MAV_CMD_DO_WINCH, 1))
    assert isinstance(odd, Deny) and odd.result == mav.MAV_RESULT_UNSUPPORTED and "DO_WINCH" in odd.reason
    assert map_command(ctx(), cmd(mav.MAV_CMD_REQUEST_MESSAGE, 148)) == Local("request_message", (148.0,))


@pytest.mark.parametrize("kind", ["uav", "uquad"])
def test_no_task_before_the_robot_offers_it(kind: str) -> None:
    out = map_command(ctx(kind=kind, available=frozenset()), cmd(mav.MAV_CMD_NAV_LAND))
    assert isinstance(out, Deny) and kind in out.reason


def test_a_mission_with_a_take_off_started_on_the_ground_takes_off_first() -> None:
    plan = Plan(waypoints=PLAN.waypoints, seqs=(1, 2, 3, 4), speed=None, count=6, takeoff=True, takeoff_height=15.0,
                finish="land")
    start = map_command(ctx(plan=plan, airborne=False), cmd(mav.MAV_CMD_MISSION_START, 0, 0))
    assert start == Send(gri.TakeOff(height=15.0), "mission_takeoff", 0)
    own = Plan(waypoints=PLAN.waypoints, seqs=(1, 2, 3, 4), speed=None, count=6, takeoff=True)
    assert map_command(ctx(plan=own, airborne=False), cmd(mav.MAV_CMD_MISSION_START, 0, 0)) == Send(
        gri.TakeOff(height=10.0), "mission_takeoff", 0)  # the robot's own take-off height
    # airborne: the take-off item is skipped, the path flown
    flying = map_command(ctx(plan=plan), cmd(mav.MAV_CMD_MISSION_START, 0, 0))
    assert isinstance(flying, Send) and flying.role == "mission" and isinstance(flying.request, gri.FollowPath)
