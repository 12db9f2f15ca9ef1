"""MTData layouts, data formats, the Pose struct and the status-byte rule."""

from __future__ import annotations

import math
import struct

import msgspec
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from modules.lidar_logger.mtdata import (
    MODE_CALIB,
    MODE_ORIENT,
    MODE_POSITION,
    MODE_RAW,
    MODE_RAWGPS,
    MODE_STATUS,
    MODE_TEMP,
    MODE_VELOCITY,
    POSE_MODE,
    POSE_SETTINGS,
    SET_CALIB_NO_MAG,
    SET_FORMAT_DOUBLE,
    SET_FORMAT_FLOAT,
    SET_FORMAT_FP1220,
    SET_FORMAT_FP1632,
    SET_ORIENT_EULER,
    SET_TS_SAMPLE_COUNTER,
    SET_TS_UTC,
    MTDataError,
    Pose,
    UtcTime,
    decode_pose,
    encode_pose_payload,
    encode_values,
    is_reliable,
    layout,
    utc_from_posix,
    utc_to_posix,
)

UTC = UtcTime(nano=77_000_000, year=2010, month=9, day=10, hour=7, minute=30, second=55, flags=1)


def pose(status: int = 7, **kw) -> Pose:
    base = dict(
        utc=UTC,
        euler=(-0.49730527, 0.7657041, -138.17576599),
        lla=(37.42611694, -6.00321293, 62.1961937),
        vel=(-0.27509207, -0.05818643, 0.13713859),
        status=status,
        valid=1 if status == 7 else 0,
    )
    base.update(kw)
    return Pose(**base)


def test_reference_layout_size() -> None:
    # protocols.md §1.3: mode 0x0834 + settings 0x0007 (Euler + sample counter + UTC) is 51 data bytes
    assert layout(0x0834, 0x0007).length == 51
    assert layout(POSE_MODE, POSE_SETTINGS).length == 3 * 3 * 6 + 1 + 12


def test_every_block_counts_in_the_cmt_order() -> None:
    lay = layout(
        MODE_RAW
        | MODE_RAWGPS
        | MODE_TEMP
        | MODE_CALIB
        | MODE_ORIENT
        | MODE_POSITION
        | MODE_VELOCITY
        | MODE_STATUS,
        SET_ORIENT_EULER | SET_CALIB_NO_MAG | SET_TS_SAMPLE_COUNTER | SET_TS_UTC,
    )
    assert lay.orient == 20 + 44 + 4 + 24
    assert lay.position == lay.orient + 12
    assert lay.velocity == lay.position + 12
    assert lay.status == lay.velocity + 12
    assert lay.sample_counter == lay.status + 1
    assert lay.utc == lay.sample_counter + 2
    assert lay.length == lay.utc + 12


def test_fixed_16_32_bytes_are_fraction_then_integer() -> None:
    assert encode_values([1.5], SET_FORMAT_FP1632) == bytes.fromhex("800000000001")
    assert encode_values([-0.5], SET_FORMAT_FP1632) == bytes.fromhex("80000000FFFF")
    assert encode_values([2.0], SET_FORMAT_FP1220) == struct.pack(">i", 2 << 20)


@pytest.mark.parametrize(
    "fmt, tol",
    [
        (SET_FORMAT_FLOAT, 5e-6),
        (SET_FORMAT_FP1220, 1e-6),
        (SET_FORMAT_FP1632, 3e-10),
        (SET_FORMAT_DOUBLE, 0.0),
    ],
)
def test_pose_roundtrip_in_every_data_format(fmt: int, tol: float) -> None:
    settings = SET_TS_UTC | SET_ORIENT_EULER | fmt
    p = pose(euler=(1.25, -0.5, 120.0), lla=(37.42611694, -6.00321293, 62.1961937), vel=(1.0, -2.0, 0.25))
    got = decode_pose(encode_pose_payload(p, POSE_MODE, settings), POSE_MODE, settings)
    for a, b in zip((*got.euler, *got.vel), (*p.euler, *p.vel), strict=True):
        assert abs(a - b) <= max(tol, 1e-6 * abs(b) if fmt == SET_FORMAT_FLOAT else 0)
    assert got.utc == UTC and got.status == 7 and got.valid == 1
    if fmt == SET_FORMAT_FP1632:
        assert all(abs(a - b) < 3e-10 for a, b in zip(got.lla, p.lla, strict=True))


@pytest.mark.parametrize("status, valid", [(0, 0), (1, 0), (5, 0), (3, 0), (7, 1), (0x1F, 1)])
def test_valid_only_with_selftest_xkf_and_gps_fix(status: int, valid: int) -> None:
    payload = encode_pose_payload(pose(status=status), POSE_MODE, POSE_SETTINGS)
    assert decode_pose(payload, POSE_MODE, POSE_SETTINGS).valid == valid
    assert is_reliable(status) == bool(valid)


def test_length_mismatch_is_an_error() -> None:
    payload = encode_pose_payload(pose(), POSE_MODE, POSE_SETTINGS)
    with pytest.raises(MTDataError, match="expected 67"):
        decode_pose(payload[:-1], POSE_MODE, POSE_SETTINGS)


def test_missing_blocks_are_an_error() -> None:
    settings = SET_ORIENT_EULER | SET_FORMAT_FP1632
    payload = encode_pose_payload(pose(), POSE_MODE, settings)
    with pytest.raises(MTDataError, match="UTC"):
        decode_pose(payload, POSE_MODE, settings)


def test_out_of_range_values_are_refused() -> None:
    settings = SET_TS_UTC | SET_ORIENT_EULER | SET_FORMAT_DOUBLE
    bad = msgspec.structs.replace(pose(), lla=(95.0, 0.0, 0.0))
    with pytest.raises(MTDataError, match="out of range"):
        decode_pose(encode_pose_payload(bad, POSE_MODE, settings), POSE_MODE, settings)
    nan = msgspec.structs.replace(pose(), euler=(math.nan, 0.0, 0.0))
    with pytest.raises(MTDataError, match="non-finite"):
        decode_pose(encode_pose_payload(nan, POSE_MODE, settings), POSE_MODE, settings)
    month13 = bytearray(encode_pose_payload(pose(), POSE_MODE, settings))
    month13[-6] = 13
    with pytest.raises(MTDataError, match="out of range"):
        decode_pose(bytes(month13), POSE_MODE, settings)


def test_utc_conversions() -> None:
    t = utc_to_posix(UTC)
    assert t == pytest.approx(1284103855.077)
    back = utc_from_posix(t)
    assert (back.year, back.month, back.day, back.hour, back.minute, back.second) == (2010, 9, 10, 7, 30, 55)
    assert abs(back.nano - 77_000_000) < 1000
    assert math.isnan(
        utc_to_posix(UtcTime(nano=0, year=0, month=0, day=0, hour=0, minute=0, second=0, flags=0))
    )


@settings(max_examples=100, deadline=None)
@given(
    st.floats(-180, 180),
    st.floats(-90, 90),
    st.floats(-180, 180),
    st.floats(-90, 90),
    st.floats(-180, 180),
    st.floats(-500, 9000),
    st.floats(-99, 99),
)
def test_fixed_16_32_keeps_any_pose_to_a_nanodegree(r, p, y, lat, lon, alt, v) -> None:
    src = pose(euler=(r, p, y), lla=(lat, lon, alt), vel=(v, -v, v / 2))
    got = decode_pose(encode_pose_payload(src), POSE_MODE, POSE_SETTINGS)
    for a, b in zip((*got.euler, *got.lla, *got.vel), (*src.euler, *src.lla, *src.vel), strict=True):
        assert abs(a - b) <= 2**-32
