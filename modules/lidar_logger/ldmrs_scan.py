"""LD-MRS scan messages (data type 0x2202): numpy decoding, encoding, Cartesian points, time offsets.

Payload (little-endian): a 44-byte scan header then N points of 10 bytes (reference/protocols.md §2.2).
Points are decoded in one ``np.frombuffer`` with a structured dtype; nothing loops per point in Python.

Scanner frame (DIN 70000, as libsick_ldmrs): x forward through the window, y left, z up. Horizontal angle
h = ticks/32 degrees, positive to the left. The four layers look at elevations of -1.2°, -0.4°, +0.4°, +1.2°
(layer 0 lowest): libsick_ldmrs ``LuxBase::getVAngleOfLayer`` spaces the 4 layers 0.8° apart symmetric about
0° (with beam tilt 0, as on the 4-layer LD-MRS), and the seed's own Figure 42 shows the same angles
(-0.4° for channel 1, -1.2° for channel 0). x = d·cos(e)·cos(h), y = d·cos(e)·sin(h), z = d·sin(e).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from modules.lidar_logger.ldmrs_proto import POINT_SIZE, SCAN_HEADER_SIZE, LdmrsProtocolError

TICKS_PER_DEGREE = 32
TICKS_PER_ROTATION = 360 * TICKS_PER_DEGREE
LAYER_SPACING_DEG = 0.8
NTP_UNIX_OFFSET = 2_208_988_800
"""Seconds from 1900-01-01 (NTP era 0) to 1970-01-01."""

SCAN_HEADER = struct.Struct("<HHHQQHhhHhhhhhhH")
WIRE_POINT_DTYPE = np.dtype([
    ("layer_echo", "u1"), ("flags", "u1"), ("angle", "<i2"), ("distance", "<u2"),
    ("echo_width", "<u2"), ("reserved", "<u2"),
])
assert SCAN_HEADER.size == SCAN_HEADER_SIZE and WIRE_POINT_DTYPE.itemsize == POINT_SIZE

# Physical ranges of a decoded scan (LD-MRS operating manual): the horizontal field is +50°..-60° (1600..-1920
# ticks), 4 layers, up to 4 echoes per beam (0..3), one rotation = 11520 ticks. A scan with anything outside is
# damaged (or not an LD-MRS) and is dropped whole: no point of it is used.
MIN_ANGLE_TICKS = -60 * TICKS_PER_DEGREE
MAX_ANGLE_TICKS = 50 * TICKS_PER_DEGREE
MAX_LAYER = 3
MAX_ECHO = 3

# scan-level flags word
SCAN_GROUND_LABELED = 0x0001
SCAN_DIRT_LABELED = 0x0002
SCAN_RAIN_LABELED = 0x0004
SCAN_REAR_MIRROR = 0x0400


def layer_elevation_deg(layer: np.ndarray | int) -> np.ndarray:
    """Elevation of a layer's beams in degrees: (layer - 1.5) × 0.8°."""
    return (np.asarray(layer, dtype=np.float64) - 1.5) * LAYER_SPACING_DEG


def ntp_to_posix(ntp: np.ndarray | int) -> np.ndarray:
    """64-bit NTP (32.32 seconds since 1900) → POSIX seconds as float64."""
    ntp = np.asarray(ntp, dtype=np.uint64)
    sec = (ntp >> np.uint64(32)).astype(np.float64) - NTP_UNIX_OFFSET
    frac = (ntp & np.uint64(0xFFFFFFFF)).astype(np.float64) / 4294967296.0
    return sec + frac


def posix_to_ntp(t: float) -> int:
    sec = int(np.floor(t))
    frac = int(round((t - sec) * 4294967296.0))
    if frac >= 1 << 32:
        sec, frac = sec + 1, frac - (1 << 32)
    return ((sec + NTP_UNIX_OFFSET) << 32) | frac


_COS_LAYER = np.cos(np.radians(layer_elevation_deg(np.arange(16))))
_SIN_LAYER = np.sin(np.radians(layer_elevation_deg(np.arange(16))))
"""cos and sin of the elevation of the 16 layer numbers a 4-bit field can hold."""


def cartesian(angle_ticks: np.ndarray, distance_cm: np.ndarray, layer: np.ndarray) -> np.ndarray:
    """(N, 3) points in metres in the scanner frame."""
    h = np.radians(np.asarray(angle_ticks, dtype=np.float64) / TICKS_PER_DEGREE)
    lay = np.asarray(layer)
    d = np.asarray(distance_cm, dtype=np.float64) / 100.0
    if lay.ndim == 1 and lay.dtype.kind in "ui" and len(lay) and int(lay.min()) >= 0 and int(lay.max()) < 16:
        cos_e, sin_e = _COS_LAYER[lay], _SIN_LAYER[lay]  # the same values, looked up instead of computed per point
    else:
        e = np.radians(layer_elevation_deg(lay))
        cos_e, sin_e = np.cos(e), np.sin(e)
    out = np.empty((len(d), 3))
    de = d * cos_e
    out[:, 0] = de * np.cos(h)
    out[:, 1] = de * np.sin(h)
    out[:, 2] = d * sin_e
    return out


def time_offsets_us(angle_ticks: np.ndarray, start_ticks: np.ndarray | int, end_ticks: np.ndarray | int,
                    start_ntp: np.ndarray | int, end_ntp: np.ndarray | int) -> np.ndarray:
    """Microseconds from scan start, interpolated linearly in angle between the start and end timestamps.

    Scan quantities may be scalars or per-point arrays (broadcast); a scan whose start and end angles are
    equal gets offsets of 0.
    """
    if all(isinstance(q, int) for q in (start_ticks, end_ticks, start_ntp, end_ntp)):  # one scan: scalars
        span = start_ticks - end_ticks
        if span == 0:
            return np.zeros(len(angle_ticks), dtype=np.int64)
        lag = (end_ntp - start_ntp) & 0xFFFF_FFFF_FFFF_FFFF
        lag = lag - (1 << 64) if lag >= 1 << 63 else lag  # as the uint64 difference viewed as int64 below
        frac = (start_ticks - np.asarray(angle_ticks, dtype=np.float64)) / span
        return np.rint(float(lag) * 1e6 / 4294967296.0 * frac).astype(np.int64)
    diff = (np.asarray(end_ntp, dtype=np.uint64) - np.asarray(start_ntp, dtype=np.uint64)).view(np.int64)
    duration_us = diff.astype(np.float64) * 1e6 / 4294967296.0
    start = np.asarray(start_ticks, dtype=np.int64)
    span = start - np.asarray(end_ticks, dtype=np.int64)
    frac = (start - np.asarray(angle_ticks, dtype=np.float64)) / np.where(span == 0, 1, span)
    return np.where(span == 0, 0.0, np.rint(duration_us * frac)).astype(np.int64)


@dataclass(frozen=True)
class Scan:
    """One decoded scan; per-point fields are numpy views on the received payload."""

    scan_number: int
    scanner_status: int
    sync_phase_offset: int
    start_ntp: int
    end_ntp: int
    ticks_per_rotation: int
    start_angle: int
    end_angle: int
    mounting: tuple[int, int, int, int, int, int]
    """yaw, pitch, roll [ticks]; x, y, z [cm] as configured in the scanner."""
    scan_flags: int
    points: np.ndarray
    """Structured array with ``WIRE_POINT_DTYPE``."""

    @property
    def n_points(self) -> int:
        return len(self.points)

    @property
    def layer(self) -> np.ndarray:
        return self.points["layer_echo"] & 0x0F

    @property
    def echo(self) -> np.ndarray:
        return self.points["layer_echo"] >> 4

    @property
    def wire_flags(self) -> np.ndarray:
        return self.points["flags"]

    @property
    def angle_ticks(self) -> np.ndarray:
        return self.points["angle"]

    @property
    def angles_rad(self) -> np.ndarray:
        return np.radians(self.points["angle"] / TICKS_PER_DEGREE)

    @property
    def distance_cm(self) -> np.ndarray:
        return self.points["distance"]

    @property
    def distances_m(self) -> np.ndarray:
        return self.points["distance"] / 100.0

    @property
    def echo_width_cm(self) -> np.ndarray:
        return self.points["echo_width"]

    @property
    def echo_width_m(self) -> np.ndarray:
        return self.points["echo_width"] / 100.0

    @property
    def start_time(self) -> float:
        return float(ntp_to_posix(self.start_ntp))

    @property
    def end_time(self) -> float:
        return float(ntp_to_posix(self.end_ntp))

    def time_offsets_us(self) -> np.ndarray:
        return time_offsets_us(self.points["angle"], self.start_angle, self.end_angle, self.start_ntp,
                               self.end_ntp)

    def cartesian(self) -> np.ndarray:
        return cartesian(self.points["angle"], self.points["distance"], self.layer)


def decode_scan(payload: bytes) -> Scan:
    """Decode a 0x2202 payload. Raises LdmrsProtocolError if its size disagrees with its point count."""
    if len(payload) < SCAN_HEADER_SIZE:
        raise LdmrsProtocolError(f"scan payload of {len(payload)} bytes, header alone is {SCAN_HEADER_SIZE}")
    (number, status, sync, start_ntp, end_ntp, ticks, start_angle, end_angle, n, m_yaw, m_pitch, m_roll,
     m_x, m_y, m_z, flags) = SCAN_HEADER.unpack_from(payload)
    if len(payload) != SCAN_HEADER_SIZE + POINT_SIZE * n:
        raise LdmrsProtocolError(f"scan {number}: {n} points need {SCAN_HEADER_SIZE + POINT_SIZE * n} bytes, "
                                 f"payload has {len(payload)}")
    points = np.frombuffer(payload, dtype=WIRE_POINT_DTYPE, count=n, offset=SCAN_HEADER_SIZE)
    _check_ranges(number, ticks, start_angle, end_angle, points)
    return Scan(number, status, sync, start_ntp, end_ntp, ticks, start_angle, end_angle,
                (m_yaw, m_pitch, m_roll, m_x, m_y, m_z), flags, points)


def _check_ranges(number: int, ticks: int, start: int, end: int, points: np.ndarray) -> None:
    """LdmrsProtocolError naming the first value outside the scanner's physical ranges (vectorised)."""
    if ticks != TICKS_PER_ROTATION:
        raise LdmrsProtocolError(f"scan {number}: {ticks} ticks per rotation, an LD-MRS has {TICKS_PER_ROTATION}")
    for name, value in (("start angle", start), ("end angle", end)):
        if not MIN_ANGLE_TICKS <= value <= MAX_ANGLE_TICKS:
            raise LdmrsProtocolError(f"scan {number}: {name} {value} ticks outside "
                                     f"[{MIN_ANGLE_TICKS}, {MAX_ANGLE_TICKS}]")
    if not len(points):
        return
    angle = points["angle"]
    bad = (angle < MIN_ANGLE_TICKS) | (angle > MAX_ANGLE_TICKS)
    if bad.any():
        raise LdmrsProtocolError(f"scan {number}: point angle {int(angle[bad][0])} ticks outside "
                                 f"[{MIN_ANGLE_TICKS}, {MAX_ANGLE_TICKS}]")
    layer_echo = points["layer_echo"]
    if int((layer_echo & 0x0F).max()) > MAX_LAYER or int((layer_echo >> 4).max()) > MAX_ECHO:
        raise LdmrsProtocolError(f"scan {number}: a point's layer > {MAX_LAYER} or echo > {MAX_ECHO}")


def encode_scan(scan: Scan) -> bytes:
    """Inverse of ``decode_scan`` (the simulator's side)."""
    pts = np.ascontiguousarray(scan.points, dtype=WIRE_POINT_DTYPE)
    head = SCAN_HEADER.pack(scan.scan_number & 0xFFFF, scan.scanner_status, scan.sync_phase_offset,
                            scan.start_ntp, scan.end_ntp, scan.ticks_per_rotation, scan.start_angle,
                            scan.end_angle, len(pts), *scan.mounting, scan.scan_flags)
    return head + pts.tobytes()


def make_points(layer: np.ndarray, echo: np.ndarray, flags: np.ndarray, angle_ticks: np.ndarray,
                distance_cm: np.ndarray, echo_width_cm: np.ndarray) -> np.ndarray:
    """Assemble a wire point array from columns."""
    pts = np.zeros(len(angle_ticks), dtype=WIRE_POINT_DTYPE)
    pts["layer_echo"] = (np.asarray(layer) & 0x0F) | ((np.asarray(echo) & 0x0F) << 4)
    pts["flags"] = flags
    pts["angle"] = angle_ticks
    pts["distance"] = distance_cm
    pts["echo_width"] = echo_width_cm
    return pts
