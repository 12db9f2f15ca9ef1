"""Every DSP message round-trips; scaling and rounding as docs/dsp_protocol.md §4.3 says; ranges refused."""

from __future__ import annotations

import math
import struct
import typing

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bbcs.contracts import dsp as p
from modules.dsp import codec
from modules.dsp.framing import MAX_PAYLOAD, FrameParser, crc16

F32_MAX = p.F32_MAX


def f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


finite = st.floats(min_value=-1e30, max_value=1e30, allow_nan=False, allow_infinity=False).map(f32)


def bounded(lo: float, hi: float, *, hi_open: bool = False) -> st.SearchStrategy[float]:
    return st.floats(min_value=lo, max_value=hi, allow_nan=False, exclude_max=hi_open).map(f32).filter(
        lambda v: lo <= v and (v < hi if hi_open else v <= hi))


lat_grid = st.integers(-900_000, 900_000).map(lambda i: i / 10_000)
lon_grid = st.integers(-1_800_000, 1_800_000).map(lambda i: i / 10_000)

COMMAND_STRATEGIES = {
    p.SetSpeed: st.builds(p.SetSpeed, speed=bounded(0.0, 30.0)),
    p.SetTelemetryMask: st.builds(p.SetTelemetryMask, mask=st.integers(0, p.TELEMETRY_ALL)),
    p.SetStateTransmission: st.builds(p.SetStateTransmission, enable=st.booleans(),
                                      period_ms=st.integers(10, 60_000)),
    p.ClearError: st.just(p.ClearError()),
    p.SetTracking: st.builds(p.SetTracking, enable=st.booleans()),
    p.InvalidatePath: st.just(p.InvalidatePath()),
    p.SetHelicopterType: st.builds(p.SetHelicopterType, heli_type=st.sampled_from(p.HeliType)),
    p.SetPid: st.builds(
        lambda axis, g, awu, sat: p.SetPid(axis=axis, kp=g[0], ki=g[1], kd=g[2], integral=g[3],
                                           reference=g[4], offset=g[5], awu_min=min(awu), awu_max=max(awu),
                                           sat_low=min(sat), sat_high=max(sat)),
        st.sampled_from(p.Axis), st.tuples(*[finite] * 6), st.tuples(finite, finite),
        st.tuples(finite, finite)),
    p.SetMode: st.builds(p.SetMode, mode=st.sampled_from(p.Mode)),
    p.SetHeading: st.builds(p.SetHeading, heading_deg=bounded(-180.0, 180.0, hi_open=True)),
    p.AddWaypoint: st.builds(p.AddWaypoint, lat=lat_grid, lon=lon_grid, alt=finite),
    p.SetRefs: st.builds(p.SetRefs, ref_altura=finite, error_longitudinal=finite, error_lateral=finite,
                         ref_heading=bounded(-math.pi, math.pi, hi_open=True),
                         ref_rpm_motor=bounded(0.0, 1800.0)),
    p.SetPanTiltMode: st.builds(p.SetPanTiltMode, mode=st.sampled_from(p.PanTiltMode)),
    p.SetPanTiltAngles: st.builds(p.SetPanTiltAngles, pan_deg=bounded(-180.0, 180.0),
                                  tilt_deg=bounded(-90.0, 90.0)),
    p.SetPanTiltTarget: st.builds(p.SetPanTiltTarget, lat=lat_grid, lon=lon_grid, alt=finite),
    p.Abort: st.just(p.Abort()),
    p.Ping: st.just(p.Ping()),
}

def tel(alias: object) -> st.SearchStrategy[float]:
    """Floats within the physical range a telemetry type declares (protocol.py)."""
    meta = typing.get_args(alias)[1]
    return bounded(meta.ge, meta.le)


telemetry = st.builds(
    p.Telemetry,
    time_ms=st.integers(0, 0xFFFFFFFF),
    position=st.none() | st.builds(p.TelPosition,
                                   lat=st.integers(-900_000_000, 900_000_000).map(lambda i: i / 1e7),
                                   lon=st.integers(-1_800_000_000, 1_800_000_000).map(lambda i: i / 1e7),
                                   alt=tel(p.TelAlt)),
    attitude=st.none() | st.builds(p.TelAttitude, roll=tel(p.Angle180), pitch=tel(p.Angle90),
                                   yaw=bounded(-180.0, 180.0, hi_open=True)),
    velocity=st.none() | st.builds(p.TelVelocity, vn=tel(p.TelSpeed), ve=tel(p.TelSpeed), vd=tel(p.TelSpeed)),
    angular_rate=st.none() | st.builds(p.AngularRate, p=tel(p.TelRate), q=tel(p.TelRate), r=tel(p.TelRate)),
    heading=st.none() | bounded(-180.0, 180.0, hi_open=True),
    status=st.none() | st.builds(p.DspStatus, mode=st.integers(0, 6), tracking=st.booleans(),
                                 path_valid=st.booleans(), airborne=st.booleans(),
                                 queue_length=st.integers(0, p.WAYPOINT_QUEUE_CAPACITY)),
    nav=st.none() | st.builds(p.NavTarget, lat=lat_grid, lon=lon_grid, alt=tel(p.TelAlt),
                              distance=tel(p.TelDistance)),
    speed=st.none() | st.builds(p.SpeedInfo, commanded=tel(p.TelCommandedSpeed), ground=tel(p.TelGroundSpeed)),
    pan_tilt=st.none() | st.builds(p.PanTiltState, mode=st.integers(0, 2), pan=tel(p.Angle180),
                                   tilt=tel(p.Angle90)),
    error_code=st.none() | st.integers(0, 0xFFFF),
    engine=st.none() | st.builds(p.Engine, rotor_rpm=tel(p.TelRpm), battery_v=tel(p.TelVolts)),
)

REPLY_STRATEGIES = {
    p.Ack: st.builds(p.Ack, acked_id=st.integers(0, 255), acked_seq=st.integers(0, 255),
                     status=st.integers(0, 0xFFFF)),
    p.DspError: st.builds(p.DspError, time_ms=st.integers(0, 0xFFFFFFFF), code=st.integers(0, 0xFFFF),
                          related_id=st.integers(0, 255)),
    p.Telemetry: telemetry,
}


def test_every_message_type_has_a_strategy_and_a_layout() -> None:
    assert set(COMMAND_STRATEGIES) == set(p.COMMANDS)
    assert set(REPLY_STRATEGIES) == set(p.REPLIES)
    assert set(codec.PC_TO_DSP_LENGTHS) == {int(c.MSG_ID) for c in p.COMMANDS}
    assert set(codec.DSP_TO_PC_LENGTHS) == {int(c.MSG_ID) for c in p.REPLIES}


@pytest.mark.parametrize("cls", list(COMMAND_STRATEGIES) + list(REPLY_STRATEGIES), ids=lambda c: c.__name__)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_round_trip(cls: type[p.Message], data: st.DataObject) -> None:
    strategy = COMMAND_STRATEGIES[cls] if cls in COMMAND_STRATEGIES else REPLY_STRATEGIES[cls]
    msg = data.draw(strategy)
    seq = data.draw(st.integers(0, 255))
    frame_bytes = codec.encode(msg, seq)
    lengths = codec.PC_TO_DSP_LENGTHS if cls in p.COMMANDS else codec.DSP_TO_PC_LENGTHS
    frames = FrameParser(lengths).feed(frame_bytes)
    assert len(frames) == 1
    assert frames[0].msg_id == msg.MSG_ID and frames[0].seq == seq
    assert codec.decode(frames[0]) == msg  # values drawn on the wire's grids come back exactly
    assert codec.encode(codec.decode(frames[0]), seq) == frame_bytes


def test_fixed_layout_sizes_match_the_document() -> None:
    expected = {p.SetSpeed: 4, p.SetTelemetryMask: 4, p.SetStateTransmission: 3, p.ClearError: 0,
                p.SetTracking: 1, p.InvalidatePath: 0, p.SetHelicopterType: 1, p.SetPid: 41, p.SetMode: 1,
                p.SetHeading: 4, p.AddWaypoint: 12, p.SetRefs: 20, p.SetPanTiltMode: 1, p.SetPanTiltAngles: 8,
                p.SetPanTiltTarget: 12, p.Abort: 0, p.Ping: 0}
    for cls, size in expected.items():
        assert codec.PC_TO_DSP_LENGTHS[int(cls.MSG_ID)] == {size}, cls.__name__
    assert codec.DSP_TO_PC_LENGTHS[p.MsgId.ACK] == {4}
    assert codec.DSP_TO_PC_LENGTHS[p.MsgId.ERROR] == {7}
    assert codec.telemetry_size(p.TELEMETRY_ALL) == 107
    assert codec.telemetry_size(0) == 8


def test_waypoint_byte_layout_is_little_endian_e4() -> None:
    payload = codec.encode_payload(p.AddWaypoint(lat=37.4117, lon=-6.0025, alt=30.5))
    assert payload == struct.pack("<iif", 374117, -60025, 30.5)
    assert codec.encode(p.SetTracking(enable=False), 7) == bytes.fromhex("a55a0105070013 80".replace(" ", ""))


def test_crc_check_value_and_example_frame() -> None:
    assert crc16(b"123456789") == 0x29B1
    frame = codec.encode(p.SetTracking(enable=False), 7)
    assert frame == bytes([0xA5, 0x5A, 0x01, 0x05, 0x07, 0x00, 0x13, 0x80])


@pytest.mark.parametrize(("deg", "units"), [
    (0.0, 0), (37.4117, 374117), (-6.0025, -60025), (90.0, 900000), (-180.0, -1800000),
    (0.00004, 0), (0.00006, 1), (-0.00004, 0), (-0.00006, -1), (12.34564, 123456), (12.34566, 123457),
])
def test_latlon_scaling_rounds_to_nearest(deg: float, units: int) -> None:
    assert codec.scale_latlon(deg) == units
    assert codec.unscale_latlon(units) == units / 10_000


def test_latlon_exact_ties_round_away_from_zero() -> None:
    ties = [k + 0.5 for k in range(-5000, 5000)]
    exact = [(t / 10_000, t) for t in ties if (abs(t / 10_000) * 10_000) == abs(t)]
    assert len(exact) > 100  # plenty of doubles whose ×10^4 is exactly k + 0.5
    for deg, tie in exact:
        expected = math.floor(tie) + 1 if tie > 0 else math.ceil(tie) - 1
        assert codec.scale_latlon(deg) == expected, deg


@settings(max_examples=300, deadline=None)
@given(st.floats(min_value=-90, max_value=90, allow_nan=False))
def test_latlon_quantisation_error_is_half_a_step(deg: float) -> None:
    back = codec.unscale_latlon(codec.scale_latlon(deg))
    assert abs(back - deg) <= 0.5e-4 + 1e-12
    # 1e-4 degree of latitude is about 11.1 m: the stated resolution
    assert abs(back - deg) * 111_320 <= 5.57


@pytest.mark.parametrize("msg", [
    p.SetSpeed(speed=-0.1), p.SetSpeed(speed=30.01), p.SetSpeed(speed=math.nan), p.SetSpeed(speed=math.inf),
    p.SetTelemetryMask(mask=1 << 11), p.SetTelemetryMask(mask=-1),
    p.SetStateTransmission(enable=True, period_ms=5), p.SetStateTransmission(enable=1, period_ms=50),  # type: ignore[arg-type]
    p.SetHelicopterType(heli_type=0), p.SetHelicopterType(heli_type=5),  # type: ignore[arg-type]
    p.SetMode(mode=7), p.SetMode(mode=-1), p.SetMode(mode=True),  # type: ignore[arg-type]
    p.SetHeading(heading_deg=180.0), p.SetHeading(heading_deg=-180.01),
    p.AddWaypoint(lat=90.0001, lon=0, alt=0), p.AddWaypoint(lat=0, lon=-180.5, alt=0),
    p.AddWaypoint(lat=0, lon=0, alt=1e39), p.AddWaypoint(lat="37", lon=0, alt=0),  # type: ignore[arg-type]
    p.SetRefs(ref_altura=0, error_longitudinal=0, error_lateral=0, ref_heading=math.pi, ref_rpm_motor=0),
    p.SetRefs(ref_altura=0, error_longitudinal=0, error_lateral=0, ref_heading=0, ref_rpm_motor=1800.5),
    p.SetPanTiltMode(mode=3),  # type: ignore[arg-type]
    p.SetPanTiltAngles(pan_deg=181, tilt_deg=0), p.SetPanTiltAngles(pan_deg=0, tilt_deg=-91),
    p.SetPanTiltTarget(lat=-91, lon=0, alt=0),
    p.SetPid(axis=p.Axis.ROLL, kp=1, ki=0, kd=0, integral=0, awu_max=1, awu_min=2, reference=0, offset=0,
             sat_high=1, sat_low=0),
    p.SetPid(axis=p.Axis.ROLL, kp=1, ki=0, kd=0, integral=0, awu_max=1, awu_min=0, reference=0, offset=0,
             sat_high=-1, sat_low=0),
    p.SetPid(axis=9, kp=1, ki=0, kd=0, integral=0, awu_max=1, awu_min=0, reference=0, offset=0,  # type: ignore[arg-type]
             sat_high=1, sat_low=0),
], ids=lambda m: type(m).__name__)
def test_out_of_range_refused_at_encode(msg: p.Message) -> None:
    with pytest.raises(p.DspValueError) as info:
        codec.encode(msg, 0)
    assert type(msg).__name__ in str(info.value)


def test_refusal_names_field_value_and_range() -> None:
    with pytest.raises(p.DspValueError, match=r"SetSpeed\.speed=31\.0 is out of range \[0\.0, 30\.0\]"):
        codec.encode(p.SetSpeed(speed=31.0), 0)
    heading = r"SetHeading\.heading_deg=180\.0 is out of range \[-180\.0, 180\.0\)"
    with pytest.raises(p.DspValueError, match=heading):
        codec.encode(p.SetHeading(heading_deg=180.0), 0)


def test_bounds_survive_float32_rounding() -> None:
    """-π is a valid ref_heading but rounds below -π in binary32: the encoder nudges it inside."""
    msg = p.SetRefs(ref_altura=0, error_longitudinal=0, error_lateral=0, ref_heading=-math.pi,
                    ref_rpm_motor=0)
    back = codec.decode_payload(p.MsgId.SET_REFS, codec.encode_payload(msg))
    assert -math.pi <= back.ref_heading < math.pi  # type: ignore[attr-defined]
    p.check(back)  # the DSP's own range check accepts it
    almost = math.nextafter(180.0, 0.0)
    back = codec.decode_payload(p.MsgId.SET_HEADING, codec.encode_payload(p.SetHeading(heading_deg=almost)))
    assert back.heading_deg < 180.0  # type: ignore[attr-defined]


def test_decoding_keeps_bad_values_for_the_dsp_to_refuse() -> None:
    msg = codec.decode_payload(p.MsgId.SET_MODE, bytes([9]))
    assert msg == p.SetMode(mode=9)  # type: ignore[arg-type]
    with pytest.raises(p.DspValueError):
        p.check(msg)
    msg = codec.decode_payload(p.MsgId.SET_TRACKING, bytes([2]))
    with pytest.raises(p.DspValueError, match="must be a bool"):
        p.check(msg)


@pytest.mark.parametrize(("msg_id", "payload", "match"), [
    (p.MsgId.ACK, b"\x01\x02", "expected 4"),
    (p.MsgId.TELEMETRY, b"\x00" * 4, "shorter"),
    (p.MsgId.TELEMETRY, struct.pack("<II", 0, 1 << 12), "reserved"),
    (p.MsgId.TELEMETRY, struct.pack("<II", 0, 1) + b"\x00" * 11, "needs 20"),
    (0x7E, b"", "unknown message id"),
])
def test_decode_errors(msg_id: int, payload: bytes, match: str) -> None:
    with pytest.raises(codec.DspDecodeError, match=match):
        codec.decode_payload(msg_id, payload)


def test_telemetry_lengths_cover_every_mask() -> None:
    lengths = codec.DSP_TO_PC_LENGTHS[p.MsgId.TELEMETRY]
    assert {codec.telemetry_size(mask) for mask in range(p.TELEMETRY_ALL + 1)} == lengths
    assert max(lengths) <= MAX_PAYLOAD


def test_telemetry_mask_follows_the_fields_present() -> None:
    t = p.Telemetry(time_ms=1, heading=12.5, error_code=3)
    assert t.mask == p.TelemetryField.HEADING | p.TelemetryField.ERROR
    payload = codec.encode_payload(t)
    assert payload == struct.pack("<IIfH", 1, t.mask, 12.5, 3)
