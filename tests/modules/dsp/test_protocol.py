"""Protocol vocabulary: range checks name the field, conversions the PC does before sending, message ids."""

from __future__ import annotations

import math

import msgspec
import pytest

from bbcs.contracts import dsp as p


def test_heading_radians_to_degrees_wraps_into_range() -> None:
    assert p.heading_deg_from_rad(math.pi / 2) == pytest.approx(90.0)
    assert p.heading_deg_from_rad(-math.pi) == -180.0
    assert p.heading_deg_from_rad(math.pi) == -180.0  # [-π, π) maps onto [-180, 180)
    assert p.heading_deg_from_rad(3 * math.pi / 2) == pytest.approx(-90.0)
    for k in range(-1000, 1000):
        deg = p.heading_deg_from_rad(k * 0.00731)
        assert -180.0 <= deg < 180.0
        p.check(p.SetHeading(heading_deg=deg))


def test_telemetry_field_names_and_error_names() -> None:
    assert p.parse_telemetry_fields(["position", " STATUS"]) == 0b100001
    assert p.parse_telemetry_fields([f.name for f in p.TelemetryField]) == p.TELEMETRY_ALL == 0x7FF
    with pytest.raises(ValueError, match="unknown telemetry field 'altitude'"):
        p.parse_telemetry_fields(["altitude"])
    assert p.dsp_error_name(4) == "QUEUE_FULL" and p.dsp_error_name(77) == "UNKNOWN_77"


def test_check_accepts_bounds_and_refuses_just_past_them() -> None:
    p.check(p.SetSpeed(speed=0.0))
    p.check(p.SetSpeed(speed=p.MAX_SPEED_LIMIT))
    p.check(p.SetRefs(ref_altura=-1e30, error_longitudinal=0, error_lateral=0, ref_heading=-math.pi,
                      ref_rpm_motor=1800))
    p.check(p.AddWaypoint(lat=-90, lon=180, alt=-50))
    p.check(p.SetPanTiltAngles(pan_deg=-180, tilt_deg=90))
    with pytest.raises(p.DspValueError, match=r"SetRefs\.ref_heading=3\.14159.* is out of range"):
        p.check(p.SetRefs(ref_altura=0, error_longitudinal=0, error_lateral=0, ref_heading=math.pi,
                          ref_rpm_motor=0))
    with pytest.raises(p.DspValueError, match=r"SetPanTiltAngles\.tilt_deg=90\.0001"):
        p.check(p.SetPanTiltAngles(pan_deg=0, tilt_deg=90.0001))
    with pytest.raises(p.DspValueError, match="must be finite"):
        p.check(p.AddWaypoint(lat=math.nan, lon=0, alt=0))
    with pytest.raises(p.DspValueError, match="must be a number"):
        p.check(p.SetSpeed(speed=None))  # type: ignore[arg-type]
    with pytest.raises(p.DspValueError, match="not a DSP protocol message"):
        p.check(p.TelPosition(lat=0, lon=0, alt=0))  # type: ignore[arg-type]


def test_ids_are_unique_and_in_their_direction_ranges() -> None:
    ids = [int(c.MSG_ID) for c in (*p.COMMANDS, *p.REPLIES)]
    assert len(ids) == len(set(ids))
    assert all(0x01 <= int(c.MSG_ID) <= 0x3F for c in p.COMMANDS)
    assert all(0x80 <= int(c.MSG_ID) <= 0xFF for c in p.REPLIES)


def test_commands_travel_as_a_tagged_union_on_the_bus() -> None:
    cmds = [p.SetSpeed(speed=2.5), p.AddWaypoint(lat=37.5, lon=-6.0, alt=30.0), p.Abort()]
    data = msgspec.msgpack.encode(cmds)
    union = p.SetSpeed | p.AddWaypoint | p.Abort
    assert msgspec.msgpack.decode(data, type=list[union]) == cmds
    with pytest.raises(msgspec.ValidationError):  # ranges are enforced when the bus decodes
        msgspec.msgpack.decode(msgspec.msgpack.encode([p.SetSpeed(speed=99.0)]), type=list[union])
