"""MTi-G legacy MTData (0x32) payloads: output mode/settings, block layout, decode and encode; the Pose
struct.

The payload is a fixed sequence of blocks, each present only if its output-mode bit is set, in the order of
reference/protocols.md §1.3 (raw, GPS PVT, temperature, calibrated, orientation, auxiliary, position,
velocity, status, sample counter, UTC). Floating values use the data format chosen in the output settings:
float32, fixed 12.20, fixed 16.32 (4-byte fraction then 2-byte integer, as CMT ``getDataFP1632`` reads it)
or float64; all big-endian.

We ask for Euler + LLA + velocity + status + UTC in fixed 16.32: its 2^-32 resolution keeps latitude and
longitude to 0.03 mm, where float32 would round latitude to about 0.4 m.
"""

from __future__ import annotations

import calendar
import math
import struct
import time
from dataclasses import dataclass
from typing import Annotated

import msgspec

from bbcs.contracts.geo import DegreesSigned90, DegreesSigned180, Latitude, Longitude, SensorAltitudeEllipsoid

# --- output mode (u16) ---
MODE_TEMP = 0x0001
MODE_CALIB = 0x0002
MODE_ORIENT = 0x0004
MODE_AUX = 0x0008
MODE_POSITION = 0x0010
MODE_VELOCITY = 0x0020
MODE_STATUS = 0x0800
MODE_RAWGPS = 0x1000
MODE_RAW = 0x4000

# --- output settings (u32) ---
SET_TS_SAMPLE_COUNTER = 0x0001
SET_TS_UTC = 0x0002
SET_ORIENT_MASK = 0x000C
SET_ORIENT_QUATERNION = 0x0000
SET_ORIENT_EULER = 0x0004
SET_ORIENT_MATRIX = 0x0008
SET_CALIB_NO_ACC = 0x0010
SET_CALIB_NO_GYR = 0x0020
SET_CALIB_NO_MAG = 0x0040
SET_FORMAT_MASK = 0x0300
SET_FORMAT_FLOAT = 0x0000
SET_FORMAT_FP1220 = 0x0100
SET_FORMAT_FP1632 = 0x0200
SET_FORMAT_DOUBLE = 0x0300
SET_AUX_NO_AIN1 = 0x0400
SET_AUX_NO_AIN2 = 0x0800
SET_POSITION_MASK = 0x1C000
SET_VELOCITY_MASK = 0x60000
SET_NED = 0x80000000

POSE_MODE = MODE_ORIENT | MODE_POSITION | MODE_VELOCITY | MODE_STATUS
"""0x0834: Euler orientation, position, velocity, status byte."""
POSE_SETTINGS = SET_TS_UTC | SET_ORIENT_EULER | SET_FORMAT_FP1632
"""0x0206: UTC timestamp, Euler angles, fixed 16.32, LLA WGS84, velocity in the default X-north Z-up frame."""

# --- status byte ---
STATUS_SELFTEST_OK = 0x01
STATUS_XKF_VALID = 0x02
STATUS_GPS_FIX = 0x04
STATUS_RELIABLE = STATUS_SELFTEST_OK | STATUS_XKF_VALID | STATUS_GPS_FIX

UTC_STRUCT = struct.Struct(">IHBBBBBB")


class MTDataError(ValueError):
    """An MTData payload that does not match the configured layout or carries impossible values."""


def is_reliable(status: int) -> bool:
    """SPEC §5's 5-vs-7 rule: 5 (self-test + GPS fix, XKF not valid) is not enough; 7 is."""
    return (status & STATUS_RELIABLE) == STATUS_RELIABLE


def value_size(settings: int) -> int:
    return {SET_FORMAT_FLOAT: 4, SET_FORMAT_FP1220: 4, SET_FORMAT_FP1632: 6, SET_FORMAT_DOUBLE: 8}[
        settings & SET_FORMAT_MASK]


@dataclass(frozen=True)
class Layout:
    """Byte offsets of the blocks we read (None when absent) and the total payload length."""

    length: int
    value_size: int
    orient: int | None
    orient_count: int
    position: int | None
    velocity: int | None
    status: int | None
    sample_counter: int | None
    utc: int | None


def layout(mode: int, settings: int) -> Layout:
    """Compute the MTData layout for an output mode and settings (CMT ``Packet::getDataSize`` order)."""
    ds = value_size(settings)
    off = 0
    if mode & MODE_RAW:
        off += 20
    if mode & MODE_RAWGPS:
        off += 44
    if mode & MODE_TEMP:
        off += ds
    if mode & MODE_CALIB:
        for bit in (SET_CALIB_NO_ACC, SET_CALIB_NO_GYR, SET_CALIB_NO_MAG):
            if not settings & bit:
                off += 3 * ds
    orient = None
    orient_count = 0
    if mode & MODE_ORIENT:
        orient_count = {SET_ORIENT_QUATERNION: 4, SET_ORIENT_EULER: 3, SET_ORIENT_MATRIX: 9}.get(
            settings & SET_ORIENT_MASK, 0)
        if orient_count == 0:
            raise MTDataError(f"orientation mode bits 0x{settings & SET_ORIENT_MASK:X} are not defined")
        orient = off
        off += orient_count * ds
    if mode & MODE_AUX:
        for bit in (SET_AUX_NO_AIN1, SET_AUX_NO_AIN2):
            if not settings & bit:
                off += 2
    position = velocity = status = sc = utc = None
    if mode & MODE_POSITION:
        position = off
        off += 3 * ds
    if mode & MODE_VELOCITY:
        velocity = off
        off += 3 * ds
    if mode & MODE_STATUS:
        status = off
        off += 1
    if settings & SET_TS_SAMPLE_COUNTER:
        sc = off
        off += 2
    if settings & SET_TS_UTC:
        utc = off
        off += 12
    return Layout(off, ds, orient, orient_count, position, velocity, status, sc, utc)


# --- fixed/floating point values ---

def _decode_values(data: bytes, offset: int, count: int, settings: int) -> tuple[float, ...]:
    fmt = settings & SET_FORMAT_MASK
    if fmt == SET_FORMAT_FLOAT:
        return struct.unpack_from(f">{count}f", data, offset)
    if fmt == SET_FORMAT_DOUBLE:
        return struct.unpack_from(f">{count}d", data, offset)
    if fmt == SET_FORMAT_FP1220:
        return tuple(v / 1048576.0 for v in struct.unpack_from(f">{count}i", data, offset))
    out = []
    for i in range(count):
        frac, whole = struct.unpack_from(">Ih", data, offset + 6 * i)
        out.append(((whole << 32) | frac) / 4294967296.0)
    return tuple(out)


def encode_values(values: tuple[float, ...] | list[float], settings: int) -> bytes:
    """Encode floating values in the settings' data format (used by the simulator)."""
    fmt = settings & SET_FORMAT_MASK
    n = len(values)
    if fmt == SET_FORMAT_FLOAT:
        return struct.pack(f">{n}f", *values)
    if fmt == SET_FORMAT_DOUBLE:
        return struct.pack(f">{n}d", *values)
    if fmt == SET_FORMAT_FP1220:
        return struct.pack(f">{n}i", *(round(v * 1048576.0) for v in values))
    parts = []
    for v in values:
        fixed = round(v * 4294967296.0)
        if not -(1 << 47) <= fixed < (1 << 47):
            raise ValueError(f"{v} does not fit fixed 16.32")
        parts.append(struct.pack(">Ih", fixed & 0xFFFFFFFF, fixed >> 32))
    return b"".join(parts)


# --- the Pose struct (Table 10 of the seed) ---

class UtcTime(msgspec.Struct, frozen=True, kw_only=True):
    """MTi-G UTC time (12 bytes on the wire); ``flags``: 1 valid, 2 time valid (date maybe not), 0 invalid."""

    nano: Annotated[int, msgspec.Meta(ge=0, le=999_999_999)]
    year: Annotated[int, msgspec.Meta(ge=0, le=65535)]
    month: Annotated[int, msgspec.Meta(ge=0, le=12)]
    day: Annotated[int, msgspec.Meta(ge=0, le=31)]
    hour: Annotated[int, msgspec.Meta(ge=0, le=23)]
    minute: Annotated[int, msgspec.Meta(ge=0, le=59)]
    second: Annotated[int, msgspec.Meta(ge=0, le=60)]
    flags: Annotated[int, msgspec.Meta(ge=0, le=255)]


Speed = Annotated[float, msgspec.Meta(ge=-1000.0, le=1000.0)]


class Pose(msgspec.Struct, frozen=True, kw_only=True):
    """One MTi-G sample as the seed's shared record: utc, euler (deg), LLA (deg, deg, m), velocity (m/s),
    status byte, valid (1 only when the status byte says self-test ok, GPS fix and XKF valid)."""

    utc: UtcTime
    euler: tuple[DegreesSigned180, DegreesSigned90, DegreesSigned180]
    lla: tuple[Latitude, Longitude, SensorAltitudeEllipsoid]
    vel: tuple[Speed, Speed, Speed]
    status: Annotated[int, msgspec.Meta(ge=0, le=255)]
    valid: Annotated[int, msgspec.Meta(ge=0, le=1)]


def utc_from_posix(t: float, flags: int = 1) -> UtcTime:
    """UTC struct for POSIX time ``t`` (seconds)."""
    whole = math.floor(t)
    nano = min(int(round((t - whole) * 1e9)), 999_999_999)
    g = time.gmtime(whole)
    return UtcTime(nano=nano, year=g.tm_year, month=g.tm_mon, day=g.tm_mday, hour=g.tm_hour,
                   minute=g.tm_min, second=g.tm_sec, flags=flags)


def utc_to_posix(utc: UtcTime) -> float:
    """POSIX seconds of a UTC struct; NaN when the date is not a real date (device not yet time-valid)."""
    if utc.month < 1 or utc.day < 1:
        return math.nan
    try:
        base = calendar.timegm((utc.year, utc.month, utc.day, utc.hour, utc.minute, utc.second, 0, 0, 0))
    except (ValueError, OverflowError):
        return math.nan
    return base + utc.nano * 1e-9


def encode_utc(utc: UtcTime) -> bytes:
    return UTC_STRUCT.pack(utc.nano, utc.year, utc.month, utc.day, utc.hour, utc.minute, utc.second,
                           utc.flags)


def decode_pose(data: bytes, mode: int, settings: int, lay: Layout | None = None) -> Pose:
    """Decode an MTData payload configured with Euler, position, velocity, status and UTC into a Pose.

    Raises MTDataError on a length mismatch, a missing block, or a value outside the Pose ranges.
    """
    lay = lay or layout(mode, settings)
    if len(data) != lay.length:
        raise MTDataError(f"MTData of {len(data)} bytes, expected {lay.length} for mode 0x{mode:04X} "
                          f"settings 0x{settings:08X}")
    if (lay.orient is None or lay.orient_count != 3 or lay.position is None or lay.velocity is None
            or lay.status is None or lay.utc is None):
        raise MTDataError("output mode/settings do not carry Euler, position, velocity, status and UTC")
    euler = _decode_values(data, lay.orient, 3, settings)
    lla = _decode_values(data, lay.position, 3, settings)
    vel = _decode_values(data, lay.velocity, 3, settings)
    status = data[lay.status]
    nano, year, month, day, hour, minute, second, flags = UTC_STRUCT.unpack_from(data, lay.utc)
    raw = {
        "utc": {"nano": nano, "year": year, "month": month, "day": day, "hour": hour, "minute": minute,
                "second": second, "flags": flags},
        "euler": euler, "lla": lla, "vel": vel, "status": status, "valid": 1 if is_reliable(status) else 0,
    }
    for v in (*euler, *lla, *vel):
        if not math.isfinite(v):
            raise MTDataError("MTData carries a non-finite value")
    try:
        return msgspec.convert(raw, Pose)
    except msgspec.ValidationError as exc:
        raise MTDataError(f"MTData value out of range: {exc}") from None


def encode_pose_payload(pose: Pose, mode: int = POSE_MODE, settings: int = POSE_SETTINGS,
                        sample_counter: int = 0) -> bytes:
    """Build the MTData payload a device configured with ``mode``/``settings`` sends for ``pose``.

    Blocks we do not model (raw, temperature, calibrated, auxiliary) are filled with zeros of the right size.
    Quaternion or matrix orientation is derived from the Euler angles.
    """
    lay = layout(mode, settings)
    out = bytearray(lay.length)
    if lay.orient is not None:
        if lay.orient_count == 3:
            vals: tuple[float, ...] = tuple(pose.euler)
        else:
            vals = _orientation_values(pose.euler, lay.orient_count)
        out[lay.orient:lay.orient + lay.orient_count * lay.value_size] = encode_values(vals, settings)
    if lay.position is not None:
        out[lay.position:lay.position + 3 * lay.value_size] = encode_values(pose.lla, settings)
    if lay.velocity is not None:
        out[lay.velocity:lay.velocity + 3 * lay.value_size] = encode_values(pose.vel, settings)
    if lay.status is not None:
        out[lay.status] = pose.status
    if lay.sample_counter is not None:
        out[lay.sample_counter:lay.sample_counter + 2] = struct.pack(">H", sample_counter & 0xFFFF)
    if lay.utc is not None:
        out[lay.utc:lay.utc + 12] = encode_utc(pose.utc)
    return bytes(out)


def _orientation_values(euler: tuple[float, float, float], count: int) -> tuple[float, ...]:
    """Quaternion (q0..q3) of ZYX Euler angles in degrees: the orientation a device streams by default."""
    if count != 4:
        raise MTDataError("only Euler and quaternion orientation are encoded")
    r, p, y = (math.radians(a) / 2 for a in euler)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)
