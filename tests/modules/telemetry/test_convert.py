"""DSP telemetry → RobotTelemetry: every field mapped, absent stays None, invalid dropped and named."""

from __future__ import annotations

import math

import msgspec

from bbcs.contracts import dsp as p
from bbcs.contracts.robot import RobotTelemetry
from modules.telemetry.convert import to_robot_telemetry

FULL = p.Telemetry(
    time_ms=1000,
    position=p.TelPosition(lat=37.4, lon=-6.0, alt=22.0),
    attitude=p.TelAttitude(roll=1, pitch=2, yaw=3),
    velocity=p.TelVelocity(vn=1, ve=2, vd=-0.5),
    angular_rate=p.AngularRate(p=0, q=0, r=0),
    heading=3.0,
    status=p.DspStatus(mode=1, tracking=True, path_valid=True, airborne=True, queue_length=7),
    nav=p.NavTarget(lat=0, lon=0, alt=0, distance=-1),
    speed=p.SpeedInfo(commanded=3, ground=2.9),
    pan_tilt=p.PanTiltState(mode=0, pan=10.0, tilt=-5.0),
    error_code=4,
    engine=p.Engine(rotor_rpm=1500, battery_v=24),
)


def test_every_field():
    r, dropped = to_robot_telemetry(FULL, 123.0)
    assert dropped == []
    assert (r.position.lat, r.position.lon, r.position.alt) == (37.4, -6.0, 22.0)
    assert (r.attitude.roll, r.attitude.pitch, r.attitude.yaw) == (1, 2, 3)
    assert (r.velocity.vn, r.velocity.ve, r.velocity.vd) == (1, 2, -0.5)
    assert r.heading_deg == 3.0 and r.stamp == 123.0
    assert (r.mode, r.mode_name, r.tracking, r.path_valid, r.airborne, r.waypoints_queued) == (
        1,
        "PATH_GIVEN_HEADING",
        True,
        True,
        True,
        7,
    )
    assert (r.pan_deg, r.tilt_deg, r.pan_tilt_mode, r.error_code) == (10.0, -5.0, 0, 4)
    assert r.battery_v == 24.0
    # what goes on the bus decodes with the struct's ranges
    assert msgspec.msgpack.decode(msgspec.msgpack.encode(r), type=RobotTelemetry) == r


def test_fields_not_in_the_mask_stay_none():
    r, dropped = to_robot_telemetry(p.Telemetry(time_ms=0, heading=1.0), 0.0)
    assert dropped == [] and r.heading_deg == 1.0
    assert r.position is None and r.mode is None and r.pan_deg is None and r.error_code is None
    assert r.battery_v is None


def test_invalid_fields_dropped_and_named():
    bad = msgspec.structs.replace(
        FULL,
        position=p.TelPosition(lat=91.0, lon=0, alt=0),
        heading=math.nan,
        attitude=p.TelAttitude(roll=math.inf, pitch=0, yaw=0),
    )
    r, dropped = to_robot_telemetry(bad, 0.0)
    assert sorted(dropped) == ["attitude", "heading", "position"]
    assert r.position is None and r.heading_deg is None and r.attitude is None and r.velocity is not None


def test_a_battery_out_of_range_is_dropped_and_named():
    for volts in (math.nan, -1.0, 150.0):
        # the DSP codec's own range check would refuse these frames; the converter must not pass them either
        engine = msgspec.structs.replace(FULL.engine, battery_v=volts)
        r, dropped = to_robot_telemetry(msgspec.structs.replace(FULL, engine=engine), 0.0)
        assert dropped == ["battery"] and r.battery_v is None and r.position is not None


def test_robot_telemetry_refuses_a_battery_out_of_range_on_decode():
    good = msgspec.msgpack.encode(RobotTelemetry(stamp=1.0, battery_v=24.5))
    assert msgspec.msgpack.decode(good, type=RobotTelemetry).battery_v == 24.5
    bad = msgspec.msgpack.encode({"stamp": 1.0, "battery_v": 101.0})
    try:
        msgspec.msgpack.decode(bad, type=RobotTelemetry)
    except msgspec.ValidationError as exc:
        assert "battery_v" in str(exc)
    else:
        raise AssertionError("a 101 V battery was accepted")
