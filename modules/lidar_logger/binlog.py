"""Compact binary log: a file of fixed-size scan records and a file of per-scan compressed point blocks.

``LogFile_<date>.scans.bin``  = 16-byte header + one ``SCAN_DTYPE`` record (140 bytes) per scan
``LogFile_<date>.points.bin`` = 16-byte header + one zlib block per scan

Header: 8-byte magic (``CRLSCAN1`` / ``CRLPNTS1``), u32 record size, u32 format version (2), little-endian.
Points keep the scanner's own integer units (polar: 1/32° ticks, cm), so nothing is rounded, and the pose is
stored once per scan. A scan's block (``chunk_offset``, ``chunk_size`` in its record) inflates to five
columns of ``n_points`` values each: angle as the difference from the previous point (the scan's start angle
for the first; int16, wrapping), distance, echo width (uint16), each as its low bytes then its high bytes,
then the wire ``layer_echo`` byte and the wire flags byte. Splitting the bytes this way puts the slowly
changing high bytes together, which is what lets zlib shrink a point from 9 bytes to about 3.5.
``decode_points`` undoes it in a few numpy calls (docs/lidar_logger.md §6 shows it with numpy and zlib only).

Version 1 logs (9-byte point records, no compression) are still read.

Records are appended after each scan, the block before its record, so a power cut leaves at most one
partial trailing record or block, which the reader ignores with a warning.
"""

from __future__ import annotations

import logging
import os
import struct
import zlib
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
VERSION = 2
ZLIB_LEVEL = 1
"""Level 1: 2-3x faster than the default for 5 % more bytes (bench/lidar.py)."""
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
SCAN_DTYPE_V1 = SCAN_DTYPE
SCAN_DTYPE = np.dtype(SCAN_DTYPE_V1.descr + [
    ("chunk_offset", "<u8"),     # byte offset of the scan's compressed block in the points file
    ("chunk_size", "<u4"),       # its length in bytes
])
POINT_DTYPE = np.dtype([
    ("angle", "<i2"),            # horizontal angle, 1/32 degree ticks
    ("distance", "<u2"),         # cm
    ("echo_width", "<u2"),       # cm
    ("layer", "u1"),             # 0..3 (text log "Channel")
    ("echo", "u1"),              # 0..3 (text log "Subchannel")
    ("flags", "u1"),             # LD-MRS wire flags byte (text log flags = flags.wire_to_seed of it)
])
"""A version 1 point record; ``decode_points`` returns this layout for both versions."""


def _split_bytes(v: np.ndarray) -> bytes:
    """uint16 column → its low bytes then its high bytes."""
    return np.ascontiguousarray(v, dtype="<u2").view(np.uint8).reshape(-1, 2).T.tobytes()


def encode_points(scan: Scan) -> bytes:
    """The compressed block of one scan (see the module docstring)."""
    p = scan.points
    angle = np.asarray(p["angle"], dtype=np.int16)
    delta = np.diff(angle, prepend=np.int16(scan.start_angle)).view(np.uint16)
    raw = b"".join((_split_bytes(delta), _split_bytes(p["distance"]), _split_bytes(p["echo_width"]),
                    np.ascontiguousarray(p["layer_echo"]).tobytes(), np.ascontiguousarray(p["flags"]).tobytes()))
    return zlib.compress(raw, ZLIB_LEVEL)


def decode_points(block: bytes, n_points: int, start_angle: int) -> np.ndarray:
    """Inverse of ``encode_points``: ``n_points`` records of ``POINT_DTYPE``; ValueError if it does not fit."""
    raw = np.frombuffer(zlib.decompress(block), dtype=np.uint8)
    n = n_points
    if len(raw) != 8 * n:
        raise ValueError(f"block inflates to {len(raw)} bytes, {n} points need {8 * n}")

    def u16(k: int) -> np.ndarray:
        return raw[2 * n * k:2 * n * (k + 1)].reshape(2, n).T.copy().view("<u2")[:, 0]

    out = np.empty(n, dtype=POINT_DTYPE)
    delta = u16(0).view(np.int16)
    out["angle"] = np.cumsum(delta, dtype=np.int16) + np.int16(start_angle) if n else delta
    out["distance"] = u16(1)
    out["echo_width"] = u16(2)
    layer_echo = raw[6 * n:7 * n]
    out["layer"] = layer_echo & 0x0F
    out["echo"] = layer_echo >> 4
    out["flags"] = raw[7 * n:]
    return out


class BinaryLogWriter:
    """Appends records to ``<base>.scans.bin`` and ``<base>.points.bin``; flushed after every scan."""

    def __init__(self, base: str | os.PathLike[str]) -> None:
        base = Path(base)
        self.scans_path = base.with_name(base.name + SCANS_SUFFIX)
        self.points_path = base.with_name(base.name + POINTS_SUFFIX)
        self._scans: IO[bytes] | None = open(self.scans_path, "xb")  # noqa: SIM115
        self._points: IO[bytes] | None = open(self.points_path, "xb")  # noqa: SIM115
        self._scans.write(FILE_HEADER.pack(SCANS_MAGIC, SCAN_DTYPE.itemsize, VERSION))
        self._points.write(FILE_HEADER.pack(POINTS_MAGIC, 0, VERSION))
        self.bytes_written = 2 * HEADER_SIZE
        self.points_written = 0
        self._points_offset = HEADER_SIZE

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
        block = encode_points(scan)
        rec["chunk_offset"] = self._points_offset
        rec["chunk_size"] = len(block)
        self._points.write(block)
        self._scans.write(rec.tobytes())
        self._points.flush()
        self._scans.flush()
        self.points_written += scan.n_points
        self._points_offset += len(block)
        self.bytes_written += SCAN_DTYPE.itemsize + len(block)

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


def _read_header(path: Path, magic: bytes) -> tuple[int, int, int]:
    """(record size, version, file size) after checking the magic."""
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
    if version not in (1, VERSION):
        raise LogFormatError(f"{path}: format version {version}; this reader knows versions 1 and {VERSION}")
    return rec_size, version, size


def _read_records(path: Path, magic: bytes, dtypes: dict[int, np.dtype]) -> tuple[np.ndarray, int]:
    rec_size, version, size = _read_header(path, magic)
    dtype = dtypes[version]
    if rec_size != dtype.itemsize:
        raise LogFormatError(f"{path}: version {version} with {rec_size}-byte records; this reader expects "
                             f"{dtype.itemsize}-byte records")
    extra = (size - HEADER_SIZE) % dtype.itemsize
    if extra:
        log.warning("%s: ignoring a partial trailing record of %d bytes", path, extra)
    count = (size - HEADER_SIZE) // dtype.itemsize
    return np.fromfile(path, dtype=dtype, count=count, offset=HEADER_SIZE), version


def read_binary_records(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray, int]:
    """The scan records, every point as ``POINT_DTYPE``, and how many trailing scans lack their points."""
    scans_path, points_path = _pair(Path(path))
    scans, version = _read_records(scans_path, SCANS_MAGIC, {1: SCAN_DTYPE_V1, 2: SCAN_DTYPE})
    expected_first = np.concatenate(([0], np.cumsum(scans["n_points"], dtype=np.int64)[:-1]))
    if np.any(scans["first_point"].astype(np.int64) != expected_first):
        k = int(np.nonzero(scans["first_point"].astype(np.int64) != expected_first)[0][0])
        raise LogFormatError(f"{scans_path}: scan record {k} starts at point {int(scans['first_point'][k])}, "
                             f"expected {int(expected_first[k])}")
    if version == 1:
        points, _ = _read_records(points_path, POINTS_MAGIC, {1: POINT_DTYPE})
        complete = scans["first_point"].astype(np.int64) + scans["n_points"] <= len(points)
    else:
        _, points_version, _ = _read_header(points_path, POINTS_MAGIC)
        if points_version != version:
            raise LogFormatError(f"{points_path}: version {points_version}, its scans file has {version}")
        data = points_path.read_bytes()
        complete = scans["chunk_offset"].astype(np.int64) + scans["chunk_size"] <= len(data)
        blocks = []
        for k, rec in enumerate(scans[complete]):
            a = int(rec["chunk_offset"])
            try:
                blocks.append(decode_points(data[a:a + int(rec["chunk_size"])], int(rec["n_points"]),
                                            int(rec["start_angle"])))
            except (ValueError, zlib.error) as exc:
                raise LogFormatError(f"{points_path}: block of scan record {k} at byte {a}: {exc}") from None
        points = np.concatenate(blocks) if blocks else np.empty(0, dtype=POINT_DTYPE)
    cut = int(len(scans) - complete.sum())
    if cut and not complete[: len(scans) - cut].all():
        raise LogFormatError(f"{scans_path}: a scan before the last ones lacks its points")
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
