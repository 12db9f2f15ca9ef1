"""Mission items → a cromat path (frames converted explicitly) and the running path's progress."""

from __future__ import annotations

import math

import pytest

from cromat.mavlink.dialect import mav
from cromat.mavlink.fence import zones_of
from cromat.mavlink.plan import Item, PlanError, plan_of, progress

HOME_ALT = 12.0


def wp(seq: int, frame: int = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, z: float = 15.0, **kw: float) -> Item:
    return Item(seq=seq, frame=frame, command=mav.MAV_CMD_NAV_WAYPOINT, x=374117000 + 1000 * seq, y=-60025000,
                z=z, **kw)


def test_relative_and_amsl_frames_are_converted_explicitly() -> None:
    plan = plan_of([wp(0), wp(1, mav.MAV_FRAME_GLOBAL_INT, 40.0), wp(2, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT, 5.0)],
                   HOME_ALT)
    assert [w.alt for w in plan.waypoints] == [27.0, 40.0, 17.0]
    assert [w.lat for w in plan.waypoints] == pytest.approx([37.4117, 37.4118, 37.4119])
    assert plan.seqs == (0, 1, 2) and plan.speed is None and plan.count == 3
    with pytest.raises(PlanError, match="home"):
        plan_of([wp(0)], None)
    with pytest.raises(PlanError, match="TERRAIN"):
        plan_of([wp(0, mav.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT)], HOME_ALT)


def test_speed_items_and_unmapped_items() -> None:
    speed = Item(seq=0, frame=mav.MAV_FRAME_MISSION, command=mav.MAV_CMD_DO_CHANGE_SPEED, param2=3.0)
    plan = plan_of([speed, wp(1), wp(2)], HOME_ALT)
    assert plan.speed == 3.0 and plan.seqs == (1, 2) and plan.count == 3
    other = Item(seq=2, frame=mav.MAV_FRAME_MISSION, command=mav.MAV_CMD_DO_CHANGE_SPEED, param2=4.0)
    with pytest.raises(PlanError, match="second speed"):
        plan_of([speed, wp(1), other], HOME_ALT)
    land = Item(seq=1, frame=mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command=mav.MAV_CMD_NAV_LAND)
    with pytest.raises(PlanError, match="item 1 \\(NAV_LAND\\)"):  # a landing in the middle of the path
        plan_of([wp(0), land, wp(2)], HOME_ALT)
    loiter = Item(seq=1, frame=mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command=mav.MAV_CMD_NAV_LOITER_TIME)
    with pytest.raises(PlanError, match="item 1 \\(NAV_LOITER_TIME\\)"):
        plan_of([wp(0), loiter], HOME_ALT)
    with pytest.raises(PlanError, match="hold time"):
        plan_of([wp(0, param1=5.0)], HOME_ALT)
    assert plan_of([wp(0, param4=math.nan)], HOME_ALT).waypoints  # QGroundControl's NaN yaw: nothing asked
    with pytest.raises(PlanError, match="no waypoint"):
        plan_of([speed], HOME_ALT)


def test_progress_from_the_dsp_queue() -> None:
    # three waypoints sent from plan index 2: queue empty before it fills, then counting down, then completed
    assert progress(2, 3, 0, completed=False) == progress(2, 3, None, completed=False)
    assert progress(2, 3, 0, completed=False).current == 2
    assert progress(2, 3, 3, completed=False).current == 2
    assert progress(2, 3, 2, completed=False).reached == 3
    assert progress(2, 3, 1, completed=False).current == 4
    done = progress(2, 3, 0, completed=True)
    assert (done.current, done.reached) == (4, 5)


def test_fence_polygons_become_world_zones_and_circles_are_refused() -> None:
    def vertex(seq: int, cmd: int, lat: float, lon: float, n: int = 3) -> Item:
        return Item(seq=seq, frame=mav.MAV_FRAME_GLOBAL, command=cmd, param1=float(n), x=round(lat * 1e7),
                    y=round(lon * 1e7), mission_type=1)

    inc, exc = mav.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, mav.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
    items = [vertex(0, inc, 37.40, -6.01), vertex(1, inc, 37.42, -6.01), vertex(2, inc, 37.42, -5.99),
             vertex(3, exc, 37.411, -6.003), vertex(4, exc, 37.412, -6.003), vertex(5, exc, 37.412, -6.002)]
    puts = zones_of("uav1", items, "mavlink")
    assert [p.id for p in puts] == ["mavlink.uav1.fence0", "mavlink.uav1.fence1"]
    assert [type(p.body).__name__ for p in puts] == ["Geofence", "NoFlyZone"]
    flat = [c for v in puts[1].body.polygon for c in (v.lat, v.lon)]
    assert flat == pytest.approx([37.411, -6.003, 37.412, -6.003, 37.412, -6.002])
    circle = Item(seq=0, frame=mav.MAV_FRAME_GLOBAL, command=mav.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, param1=100.0,
                  x=374117000, y=-60025000, mission_type=1)
    with pytest.raises(PlanError, match="circles"):
        zones_of("uav1", [circle], "mavlink")
    with pytest.raises(PlanError, match="consecutive"):
        zones_of("uav1", items[:2], "mavlink")


def test_a_qgroundcontrol_plan_takes_off_flies_and_lands_or_returns() -> None:
    rel = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    takeoff = Item(seq=0, frame=rel, command=mav.MAV_CMD_NAV_TAKEOFF, x=374117000, y=-60025000, z=12.0)
    land_there = Item(seq=3, frame=rel, command=mav.MAV_CMD_NAV_LAND, x=374130000, y=-60025000)
    plan = plan_of([takeoff, wp(1), wp(2), land_there], HOME_ALT)
    assert (plan.takeoff, plan.takeoff_height, plan.finish, plan.count) == (True, 12.0, "land", 4)
    assert plan.seqs == (1, 2, 3) and plan.waypoints[-1].lat == pytest.approx(37.413)
    assert plan.waypoints[-1].alt == plan.waypoints[-2].alt == 27.0  # flown to at the last altitude, landed at
    land_here = Item(seq=2, frame=rel, command=mav.MAV_CMD_NAV_LAND)  # no point: where the path ends
    assert plan_of([wp(0), wp(1), land_here], HOME_ALT).seqs == (0, 1)
    rtl = Item(seq=2, frame=mav.MAV_FRAME_MISSION, command=mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)
    back = plan_of([wp(0), wp(1), rtl], HOME_ALT)
    assert (back.takeoff, back.finish) == (False, "rtl")
    # AMSL take-off altitude: its height above home; 0: the robot's own height
    amsl = Item(seq=0, frame=mav.MAV_FRAME_GLOBAL_INT, command=mav.MAV_CMD_NAV_TAKEOFF, z=32.0)
    assert plan_of([amsl, wp(1)], HOME_ALT).takeoff_height == 20.0
    assert plan_of([Item(seq=0, frame=rel, command=mav.MAV_CMD_NAV_TAKEOFF), wp(1)], HOME_ALT).takeoff_height is None
    with pytest.raises(PlanError, match="not above home"):
        plan_of([Item(seq=0, frame=mav.MAV_FRAME_GLOBAL_INT, command=mav.MAV_CMD_NAV_TAKEOFF, z=5.0), wp(1)], HOME_ALT)
    # a take-off after a waypoint, a landing with no path, an RTL not last: refused with the item named
    with pytest.raises(PlanError, match="item 1 \\(NAV_TAKEOFF\\)"):
        plan_of([wp(0), Item(seq=1, frame=rel, command=mav.MAV_CMD_NAV_TAKEOFF, z=10.0), wp(2)], HOME_ALT)
    with pytest.raises(PlanError, match="item 1 \\(NAV_LAND\\)"):
        plan_of([takeoff, Item(seq=1, frame=rel, command=mav.MAV_CMD_NAV_LAND)], HOME_ALT)
    with pytest.raises(PlanError, match="item 1 \\(NAV_RETURN_TO_LAUNCH\\)"):
        plan_of([wp(0), Item(seq=1, frame=2, command=mav.MAV_CMD_NAV_RETURN_TO_LAUNCH), wp(2)], HOME_ALT)
