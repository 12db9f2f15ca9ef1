"""Scan 0x2202 decoding: fields, layer geometry, time offsets, NTP time, size checks; and the flag mapping."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from modules.lidar_logger.flags import (
    FLAG_DIRT,
    FLAG_GROUND,
    FLAG_RAIN,
    FLAG_TRANSPARENT,
    seed_to_wire,
    wire_to_seed,
)
from modules.lidar_logger.ldmrs_proto import LdmrsProtocolError
from modules.lidar_logger.ldmrs_scan import (
    SCAN_HEADER,
    Scan,
    decode_scan,
    encode_scan,
    layer_elevation_deg,
    make_points,
    ntp_to_posix,
    posix_to_ntp,
)


def make_scan() -> Scan:
    pts = make_points(
        layer=np.array([1, 0, 3, 2]),
        echo=np.array([0, 0, 1, 0]),
        flags=np.array([0, 2, 4, 8]),
        angle_ticks=np.array([1600, 1592, 0, -1600]),
        distance_cm=np.array([9037, 4000, 100, 65535]),
        echo_width_cm=np.array([124, 108, 0, 65535]),
    )
    start = posix_to_ntp(1284103855.25)
    return Scan(
        1234,
        0x000B,
        17,
        start,
        start + int(0.0222 * 2**32),
        11520,
        1600,
        -1600,
        (1, -2, 3, -4, 5, -6),
        0x0404,
        pts,
    )


def test_encode_decode_roundtrip_and_header_fields() -> None:
    scan = make_scan()
    payload = encode_scan(scan)
    assert len(payload) == 44 + 10 * 4
    head = SCAN_HEADER.unpack_from(payload)
    assert head[0] == 1234 and head[8] == 4 and head[-1] == 0x0404
    back = decode_scan(payload)
    assert back.scan_number == 1234 and back.mounting == (1, -2, 3, -4, 5, -6) and back.scan_flags == 0x0404
    assert back.layer.tolist() == [1, 0, 3, 2] and back.echo.tolist() == [0, 0, 1, 0]
    assert back.wire_flags.tolist() == [0, 2, 4, 8]
    assert back.angle_ticks.tolist() == [1600, 1592, 0, -1600]
    assert back.distances_m.tolist() == [90.37, 40.0, 1.0, 655.35]
    assert back.echo_width_m.tolist() == [1.24, 1.08, 0.0, 655.35]
    assert back.angles_rad[0] == pytest.approx(math.radians(50.0))


def test_point_layout_is_the_wire_layout() -> None:
    payload = encode_scan(make_scan())
    first = payload[44:54]
    assert first == struct.pack("<BBhHHH", 0x01, 0, 1600, 9037, 124, 0)
    third = payload[64:74]
    assert third[0] == 0x13  # layer 3, echo 1


def test_size_mismatch_raises() -> None:
    payload = encode_scan(make_scan())
    with pytest.raises(LdmrsProtocolError, match="4 points need 84 bytes"):
        decode_scan(payload[:-3])
    with pytest.raises(LdmrsProtocolError, match="header alone"):
        decode_scan(payload[:20])


def test_layers_are_0_8_degrees_apart_around_zero() -> None:
    assert layer_elevation_deg(np.arange(4)).tolist() == pytest.approx([-1.2, -0.4, 0.4, 1.2])


def test_cartesian_points_in_the_scanner_frame() -> None:
    xyz = decode_scan(encode_scan(make_scan())).cartesian()
    d, h, e = 90.37, math.radians(50.0), math.radians(-0.4)
    assert xyz[0] == pytest.approx(
        [d * math.cos(e) * math.cos(h), d * math.cos(e) * math.sin(h), d * math.sin(e)]
    )
    assert xyz[2] == pytest.approx([math.cos(math.radians(1.2)), 0.0, math.sin(math.radians(1.2))])
    assert np.linalg.norm(xyz, axis=1) == pytest.approx([90.37, 40.0, 1.0, 655.35])


def test_figure_42_points_sit_on_their_layers() -> None:
    # The seed's own example: channel 1 at -0.4 deg elevation, channel 0 at -1.2 deg.
    for x, y, z, layer in [
        (0.05844890, 0.06843486, -0.00062831, 1),
        (0.02623660, 0.03018176, -0.00083770, 0),
    ]:
        elevation = math.degrees(math.atan2(z, math.hypot(x, y)))
        assert elevation == pytest.approx(layer_elevation_deg(layer), abs=0.02)


def test_time_offsets_interpolate_between_start_and_end() -> None:
    scan = decode_scan(encode_scan(make_scan()))
    offsets = scan.time_offsets_us()
    assert offsets[0] == 0 and offsets[-1] == 22200
    assert offsets[2] == 11100  # angle 0 is half-way from +50 to -50
    duration_us = (scan.end_ntp - scan.start_ntp) * 1e6 / 2**32
    assert offsets[1] == round(duration_us * 8 / 3200) == 55


def test_ntp_conversion() -> None:
    ntp = posix_to_ntp(1284103855.25)
    assert ntp >> 32 == 1284103855 + 2_208_988_800 and ntp & 0xFFFFFFFF == 1 << 30
    assert float(ntp_to_posix(ntp)) == 1284103855.25


def test_flag_mapping_is_a_bijection_with_the_documented_values() -> None:
    assert wire_to_seed(np.array([0x00, 0x01, 0x02, 0x04, 0x08])).tolist() == [
        0,
        FLAG_TRANSPARENT,
        FLAG_RAIN,
        FLAG_GROUND,
        FLAG_DIRT,
    ]
    every = np.arange(256, dtype=np.uint8)
    seed = wire_to_seed(every)
    assert len(set(seed.tolist())) == 256
    assert np.array_equal(seed_to_wire(seed), every)
    with pytest.raises(ValueError):
        seed_to_wire(np.array([0x0010]))  # FlagThresholdSwitching has no wire bit
