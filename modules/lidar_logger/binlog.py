"""Compact binary log: two append-only files of fixed-size little-endian records, readable with plain numpy.

``LogFile_<date>.scans.bin``  = 16-byte header + one ``SCAN_DTYPE`` record (128 bytes) per scan
``LogFile_<date>.points.bin`` = 16-byte header + one ``POINT_DTYPE`` record (9 bytes) per point

Header: 8-byte magic (``CRLSCAN1`` / ``CRLPNTS1``), u32 record size, u32 format version (1), little-endian.
A scan's points are ``points[first_point : first_point + n_points]``. Points keep the scanner's own integer
units (1/32° ticks, cm), so nothing is rounded; x, y, z and time offsets follow from the formulas in
docs/lidar_logger.md. Loading needs only::

    scans = np.fromfile("LogFile_....scans.bin", dtype=SCAN_DTYPE, offset=16)
    points = np.fromfile("LogFile_....points.bin", dtype=POINT_DTYPE, offset=16)

Records are appended after each scan, so a power cut leaves at most one partial trailing record, which the
reader ignores with a warning.
"""

from __future__ import annotations

import logging
import os
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import numpy as np

from modules.lidar_logger.flags import wire_to_seed
from modules.lidar_logger.ldmrs_scan import Scan, cartesian, make_points, ntp_to_posix, time_offsets_us
from modules.lidar_logger.logdata import LidarLog, LogFormatError, ScanRecord, point_scan_index
from modules.lidar_logger.mtdata import Pose, UtcTime, utc_to_posix

log = logging.getLogger("lidar_logger.binlog")

SCANS_SUFFIX = ".scans.bin"
POINTS_SUFFIX = ".points.bin"
SCANS_MAGIC = b"CRLSCAN1"
POINTS_MAGIC = b"CRLPNTS1"
VERSION = 1
FILE_HEADER = struct.Struct("<8sII")
HEADER_SIZE = FILE_HEADER.size

SCAN_DTYPE = np.dtype([
    ("index", "<u4"),            # "Scan N": scans received since StartMeasure, from 1
    ("scan_number", "<u2"),      # the scanner's own scan counter
    ("scanner_status", "<u2"),
    ("scan_flags", "<u2"),
    ("start_angle", "<i2"),      # 1/32 degree ticks
    ("end_angle", "<i2"),
    ("start_ntp", "<u8"),        # NTP 32.32 seconds since 1900 (scanner clock)
    ("end_ntp", "<u8"),
    ("first_point", "<u8"),      # index of the scan's first record in the points file
    ("n_points", "<u4"),
    ("utc_nano", "<u4"),         # MTi-G UTC of the attached pose
    ("utc_year", "<u2"),
    ("utc_month", "u1"),
    ("utc_day", "u1"),
    ("utc_hour", "u1"),
    ("utc_minute", "u1"),
    ("utc_second", "u1"),
    ("utc_flags", "u1"),
    ("euler", "<f8", (3,)),      # roll, pitch, yaw [deg]
    ("lla", "<f8", (3,)),        # latitude, longitude [deg], altitude [m]
    ("vel", "<f8", (3,)),        # [m/s]
    ("status", "u1"),            # MTi-G status byte
    ("valid", "u1"),             # 1 when status has self-test, XKF valid and GPS fix
])
POINT_DTYPE = np.dtype([
    ("angle", "<i2"),            # horizontal angle, 1/32 degree ticks
    ("distance", "<u2"),         # cm
    ("echo_width", "<u2"),       # cm
    ("layer", "u1"),             # 0..3 (text log "Channel")
    ("echo", "u1"),              # 0..3 (text log "Subchannel")
    ("flags", "u1"),             # LD-MRS wire flags byte (text log flags = flags.wire_to_seed of it)
])


class BinaryLogWriter:
    """Appends records to ``<base>.scans.bin`` and ``<base>.points.bin``; flushed after every scan."""

    def __init__(self, base: str | os.PathLike[str]) -> None:
        base = Path(base)
        self.scans_path = base.with_name(base.name + SCANS_SUFFIX)
        self.points_path = base.with_name(base.name + POINTS_SUFFIX)
        self._scans: IO[bytes] | None = open(self.scans_path, "xb")  # noqa: SIM115
        self._points: IO[bytes] | None = open(self.points_path, "xb")  # noqa: SIM115
        self._scans.write(FILE_HEADER.pack(SCANS_MAGIC, SCAN_DTYPE.itemsize, VERSION))
        self._points.write(FILE_HEADER.pack(POINTS_MAGIC, POINT_DTYPE.itemsize, VERSION))
        self.bytes_written = 2 * HEADER_SIZE
        self.points_written = 0

    def write(self, record: ScanRecord) -> None:
        if self._scans is None or self._points is None:
            raise ValueError(f"{self.scans_path} is closed")
        scan, pose, utc = record.scan, record.pose, record.pose.utc
        rec = np.zeros(1, dtype=SCAN_DTYPE)
        rec["index"] = record.index
        rec["scan_number"] = scan.scan_number
        rec["scanner_status"] = scan.scanner_status
        rec["scan_flags"] = scan.scan_flags
        rec["start_angle"] = scan.start_angle
        rec["end_angle"] = scan.end_angle
        rec["start_ntp"] = scan.start_ntp
        rec["end_ntp"] = scan.end_ntp
        rec["first_point"] = self.points_written
        rec["n_points"] = scan.n_points
        rec["utc_nano"], rec["utc_year"], rec["utc_month"], rec["utc_day"] = (
            utc.nano, utc.year, utc.month, utc.day)
        rec["utc_hour"], rec["utc_minute"], rec["utc_second"], rec["utc_flags"] = (
            utc.hour, utc.minute, utc.second, utc.flags)
        rec["euler"], rec["lla"], rec["vel"] = pose.euler, pose.lla, pose.vel
        rec["status"], rec["valid"] = pose.status, pose.valid
        pts = np.empty(scan.n_points, dtype=POINT_DTYPE)
        pts["angle"] = scan.angle_ticks
        pts["distance"] = scan.distance_cm
        pts["echo_width"] = scan.echo_width_cm
        pts["layer"] = scan.layer
        pts["echo"] = scan.echo
        pts["flags"] = scan.wire_flags
        self._points.write(pts.tobytes())
        self._scans.write(rec.tobytes())
        self._points.flush()
        self._scans.flush()
        self.points_written += scan.n_points
        self.bytes_written += SCAN_DTYPE.itemsize + POINT_DTYPE.itemsize * scan.n_points

    def close(self) -> None:
        """Flush both files to the medium and close them (closed even when a flush fails)."""
        files = [f for f in (self._points, self._scans) if f is not None]
        self._scans = self._points = None
        failure: OSError | None = None
        for f in files:
            try:
                f.flush()
                os.fsync(f.fileno())
            except OSError as exc:
                failure = failure or exc
            finally:
                f.close()
        if failure is not None:
            raise failure


def _pair(path: Path) -> tuple[Path, Path]:
    name = path.name
    for suffix in (SCANS_SUFFIX, POINTS_SUFFIX):
        if name.endswith(suffix):
            base = name[: -len(suffix)]
            return path.with_name(base + SCANS_SUFFIX), path.with_name(base + POINTS_SUFFIX)
    raise LogFormatError(f"{path}: a binary log file name ends in {SCANS_SUFFIX} or {POINTS_SUFFIX}")


def _read_records(path: Path, magic: bytes, dtype: np.dtype) -> np.ndarray:
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(HEADER_SIZE)
    except OSError as exc:
        raise LogFormatError(f"{path}: {exc}") from None
    if len(head) < HEADER_SIZE:
        raise LogFormatError(f"{path}: {len(head)} bytes, shorter than the {HEADER_SIZE}-byte header")
    got_magic, rec_size, version = FILE_HEADER.unpack(head)
    if got_magic != magic:
        raise LogFormatError(f"{path}: magic {got_magic!r}, expected {magic!r}")
    if version != VERSION or rec_size != dtype.itemsize:
        raise LogFormatError(f"{path}: version {version} with {rec_size}-byte records; this reader knows "
                             f"version {VERSION} with {dtype.itemsize}-byte records")
    extra = (size - HEADER_SIZE) % dtype.itemsize
    if extra:
        log.warning("%s: ignoring a partial trailing record of %d bytes", path, extra)
    count = (size - HEADER_SIZE) // dtype.itemsize
    return np.fromfile(path, dtype=dtype, count=count, offset=HEADER_SIZE)


def read_binary_records(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray, int]:
    """The raw scan and point record arrays, and how many trailing scans were cut off by the points file."""
    scans_path, points_path = _pair(Path(path))
    scans = _read_records(scans_path, SCANS_MAGIC, SCAN_DTYPE)
    points = _read_records(points_path, POINTS_MAGIC, POINT_DTYPE)
    end = scans["first_point"].astype(np.int64) + scans["n_points"]
    expected_first = np.concatenate(([0], np.cumsum(scans["n_points"], dtype=np.int64)[:-1]))
    if np.any(scans["first_point"].astype(np.int64) != expected_first):
        k = int(np.nonzero(scans["first_point"].astype(np.int64) != expected_first)[0][0])
        raise LogFormatError(f"{scans_path}: scan record {k} starts at point {int(scans['first_point'][k])}, "
                             f"expected {int(expected_first[k])}")
    complete = end <= len(points)
    cut = int(len(scans) - complete.sum())
    if cut:
        log.warning("%s: %d trailing scan(s) lack their points; left out", scans_path, cut)
        scans = scans[complete]
    return scans, points, cut


def read_binary_log(path: str | os.PathLike[str]) -> LidarLog:
    scans, points, cut = read_binary_records(path)
    n_points = scans["n_points"].astype(np.int64)
    total = int(n_points.sum())
    points = points[:total]
    point_scan = point_scan_index(n_points)
    per_point = scans[point_scan]
    offsets = time_offsets_us(points["angle"], per_point["start_angle"], per_point["end_angle"],
                              per_point["start_ntp"], per_point["end_ntp"])
    flags = wire_to_seed(points["flags"]).astype(np.int64)
    pose_time = np.array([utc_to_posix(_utc(rec)) for rec in scans], dtype=np.float64)
    return LidarLog(
        source=str(path), format="binary",
        scan_index=scans["index"].astype(np.int64),
        scan_number=scans["scan_number"].astype(np.int64),
        scan_flags=scans["scan_flags"].astype(np.int64),
        start_time=ntp_to_posix(scans["start_ntp"]),
        end_time=ntp_to_posix(scans["end_ntp"]),
        first_point=scans["first_point"].astype(np.int64),
        n_points=n_points,
        pose_time=pose_time,
        euler=scans["euler"].astype(np.float64),
        lla=scans["lla"].astype(np.float64),
        vel=scans["vel"].astype(np.float64),
        status=scans["status"].astype(np.int64),
        valid=scans["valid"].astype(np.int64),
        xyz=cartesian(points["angle"], points["distance"], points["layer"]),
        echo_width=points["echo_width"] / 100.0,
        flags=flags,
        layer=points["layer"].astype(np.int64),
        echo=points["echo"].astype(np.int64),
        offset_us=offsets,
        point_valid=(flags == 0).astype(np.int64),
        point_scan=point_scan,
        truncated_scans=cut,
    )


def _utc(rec: np.void) -> UtcTime:
    return UtcTime(nano=int(rec["utc_nano"]), year=int(rec["utc_year"]), month=int(rec["utc_month"]),
                   day=int(rec["utc_day"]), hour=int(rec["utc_hour"]), minute=int(rec["utc_minute"]),
                   second=int(rec["utc_second"]), flags=int(rec["utc_flags"]))


def iter_records(path: str | os.PathLike[str]) -> Iterator[ScanRecord]:
    """The scan records as the logger had them (used to re-create the text log byte for byte)."""
    scans, points, _ = read_binary_records(path)
    for rec in scans:
        a = int(rec["first_point"])
        p = points[a:a + int(rec["n_points"])]
        scan = Scan(int(rec["scan_number"]), int(rec["scanner_status"]), 0, int(rec["start_ntp"]),
                    int(rec["end_ntp"]), 11520, int(rec["start_angle"]), int(rec["end_angle"]), (0,) * 6,
                    int(rec["scan_flags"]),
                    make_points(p["layer"], p["echo"], p["flags"], p["angle"], p["distance"],
                                p["echo_width"]))
        pose = Pose(utc=_utc(rec), euler=tuple(float(v) for v in rec["euler"]),
                    lla=tuple(float(v) for v in rec["lla"]), vel=tuple(float(v) for v in rec["vel"]),
                    status=int(rec["status"]), valid=int(rec["valid"]))
        yield ScanRecord(int(rec["index"]), scan, pose)
