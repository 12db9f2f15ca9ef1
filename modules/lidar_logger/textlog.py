"""The seed's text log (Figure 42, Tables 13-14): write it scan by scan, and read it back into numpy arrays.

One block per scan, two blank lines after its points::

    Scan 1
    ScanStart 2008-12-15T00:11:20.178114 (683161 ms)
    ScanEnd 2008-12-15T00:11:20.200396 (683183 ms)
    ScanActiveTime (ms) 22
    Flags 4
    Points 738
    UTC Y2010 M09 D10 07:30:55 m000077
    Euler [-0.49730527,0.76570410,-138.17576599]
    LLA [37.42611694,-6.00321293,62.19619370]
    Vel [-0.27509207,-0.05818643,0.13713859]
    Status 7
    Valid 1
    Point num; Cartesian(x,y,z); EchoWidth; Flags; Channel; Subchannel; Offset (us); Valid; Segment;
    1; 0.05844890,0.06843486,-0.00062831; 1.24; 18; 1; 0; 0; 0; 0

ScanStart/End: the scanner's timestamp as ISO time with microseconds (truncated), and in parentheses the
milliseconds since that day's midnight. ScanActiveTime: end − start in whole milliseconds. Flags: the scan's
flags word. UTC: the MTi-G sample's date, time and milliseconds (``m`` + 6 digits). Points: x,y,z in metres in
the scanner frame, echo width in metres, seed-enum flags (``flags.py``), channel = layer, subchannel = echo,
offset from scan start in µs, valid = 1 when no flag is set, segment 0 (unused).
"""

from __future__ import annotations

import calendar
import logging
import os
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import IO

import numpy as np

from modules.lidar_logger.flags import wire_to_seed
from modules.lidar_logger.logdata import LidarLog, LogFormatError, ScanRecord, point_scan_index
from modules.lidar_logger.mtdata import UtcTime
from modules.lidar_logger.textfmt import format_points

log = logging.getLogger("lidar_logger.textlog")

POINT_HEADER = (
    "Point num; Cartesian(x,y,z); EchoWidth; Flags; Channel; Subchannel; Offset (us); Valid; Segment;")
_NTP_EPOCH = datetime(1900, 1, 1)


def date_stamp(utc: UtcTime) -> str:
    """``Y2010_M09_D10_H07M30S07``: the suffix of the run folder and its files."""
    return (f"Y{utc.year:04d}_M{utc.month:02d}_D{utc.day:02d}_"
            f"H{utc.hour:02d}M{utc.minute:02d}S{utc.second:02d}")


def format_ntp(ntp: int) -> str:
    sec, frac = ntp >> 32, ntp & 0xFFFFFFFF
    us = (frac * 1_000_000) >> 32
    stamp = _NTP_EPOCH + timedelta(seconds=sec)
    ms_of_day = (sec % 86400) * 1000 + ((frac * 1000) >> 32)
    # the fields by hand: strftime took a twentieth of the text writer's time (NTP years are all 4 digits)
    return (f"{stamp.year:04d}-{stamp.month:02d}-{stamp.day:02d}T{stamp.hour:02d}:{stamp.minute:02d}:"
            f"{stamp.second:02d}.{us:06d} ({ms_of_day} ms)")


def format_scan(record: ScanRecord) -> str:
    """The text block of one scan, including the two blank lines that end it."""
    return format_scan_bytes(record).decode("ascii")


def format_scan_bytes(record: ScanRecord) -> bytes:
    """``format_scan`` as the bytes the writer puts in the file (no str round trip for the point lines)."""
    scan, pose, utc = record.scan, record.pose, record.pose.utc
    active_ms = ((scan.end_ntp - scan.start_ntp) * 1000) >> 32
    e, p, v = pose.euler, pose.lla, pose.vel
    head = (
        f"Scan {record.index}\n"
        f"ScanStart {format_ntp(scan.start_ntp)}\n"
        f"ScanEnd {format_ntp(scan.end_ntp)}\n"
        f"ScanActiveTime (ms) {active_ms}\n"
        f"Flags {scan.scan_flags}\n"
        f"Points {scan.n_points}\n"
        f"UTC Y{utc.year:04d} M{utc.month:02d} D{utc.day:02d} "
        f"{utc.hour:02d}:{utc.minute:02d}:{utc.second:02d} "
        f"m{utc.nano // 1_000_000:06d}\n"
        f"Euler [{e[0]:.8f},{e[1]:.8f},{e[2]:.8f}]\n"
        f"LLA [{p[0]:.8f},{p[1]:.8f},{p[2]:.8f}]\n"
        f"Vel [{v[0]:.8f},{v[1]:.8f},{v[2]:.8f}]\n"
        f"Status {pose.status}\n"
        f"Valid {pose.valid}\n"
        f"{POINT_HEADER}\n"
    ).encode("ascii")
    if scan.n_points == 0:
        return head + b"\n\n"
    body = format_points(scan.cartesian(), scan.echo_width_cm, wire_to_seed(scan.wire_flags), scan.layer,
                         scan.echo, scan.time_offsets_us())
    return b"".join((head, body, b"\n\n"))


class TextLogWriter:
    """Appends scans to ``LogFile_<date>``, flushed after every scan: a crash loses at most one scan."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        # unbuffered binary: one write() per scan straight to the file, nothing held in a buffer to flush
        self._f: IO[bytes] | None = open(self.path, "xb", buffering=0)  # noqa: SIM115
        self.bytes_written = 0

    def write(self, record: ScanRecord) -> None:
        if self._f is None:
            raise ValueError(f"{self.path} is closed")
        data = format_scan_bytes(record)
        view = memoryview(data)
        while view:  # a raw write may be partial
            view = view[self._f.write(view):]
        self.bytes_written += len(data)

    def close(self) -> None:
        """Flush to the medium and close (closed even when the flush fails; the error is raised after)."""
        f, self._f = self._f, None
        if f is not None:
            try:
                f.flush()
                os.fsync(f.fileno())
            finally:
                f.close()


# --- reading ---

def _fail(path: Path, line_no: int, msg: str) -> LogFormatError:
    return LogFormatError(f"{path}:{line_no}: {msg}")


def _field(path: Path, line_no: int, line: str, key: str) -> str:
    if not line.startswith(key + " "):
        raise _fail(path, line_no, f"expected '{key} ...', found {line[:60]!r}")
    return line[len(key) + 1:]


def _int(path: Path, line_no: int, text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise _fail(path, line_no, f"not an integer: {text!r}") from None


def _scan_time(path: Path, line_no: int, text: str) -> float:
    iso = text.split(" (", 1)[0]
    try:
        return datetime.fromisoformat(iso).replace(tzinfo=UTC).timestamp()
    except ValueError:
        raise _fail(path, line_no, f"bad timestamp {iso!r}") from None


def _vector(path: Path, line_no: int, text: str) -> list[float]:
    if not (text.startswith("[") and text.endswith("]")):
        raise _fail(path, line_no, f"expected [a,b,c], found {text!r}")
    try:
        values = [float(v) for v in text[1:-1].split(",")]
    except ValueError:
        raise _fail(path, line_no, f"bad number in {text!r}") from None
    if len(values) != 3:
        raise _fail(path, line_no, f"expected 3 values, found {len(values)}")
    return values


def _utc_time(path: Path, line_no: int, text: str) -> float:
    parts = text.split()
    try:
        if len(parts) != 5 or [q[0] for q in (parts[0], parts[1], parts[2], parts[4])] != list("YMDm"):
            raise ValueError
        year, month, day = int(parts[0][1:]), int(parts[1][1:]), int(parts[2][1:])
        hour, minute, second = (int(x) for x in parts[3].split(":"))
        ms = int(parts[4][1:])
    except ValueError:
        raise _fail(path, line_no, f"bad UTC field {text!r}") from None
    if month < 1 or day < 1:
        return float("nan")
    return calendar.timegm((year, month, day, hour, minute, second, 0, 0, 0)) + ms / 1000.0


_HEADER_KEYS = ("ScanStart", "ScanEnd", "ScanActiveTime (ms)", "Flags", "Points", "UTC", "Euler", "LLA",
                "Vel", "Status", "Valid")


def read_text_log(path: str | os.PathLike[str]) -> LidarLog:
    """Parse a text log. A malformed line raises LogFormatError naming file and line; a last scan cut short
    (the file ends inside its points) is left out with a warning and counted in ``truncated_scans``."""
    path = Path(path)
    with open(path, encoding="ascii") as f:
        lines = f.read().split("\n")
    scans: list[tuple] = []
    point_lines: list[str] = []
    point_line_starts: list[int] = []
    truncated = 0
    i, n_lines = 0, len(lines)
    while i < n_lines:
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        first = i + 1
        index = _int(path, first, _field(path, first, line, "Scan"))
        if i + 13 >= n_lines:
            truncated += 1
            log.warning("%s:%d: scan %d is cut short (header incomplete); left out", path, first, index)
            break
        vals = [_field(path, i + 2 + k, lines[i + 1 + k], key) for k, key in enumerate(_HEADER_KEYS)]
        if lines[i + 12] != POINT_HEADER:
            raise _fail(path, i + 13, "expected the point column header line")
        n = _int(path, i + 6, vals[4])
        if n < 0:
            raise _fail(path, i + 6, "negative point count")
        start = i + 13
        body = lines[start:start + n]
        if start + n >= n_lines:  # the last point line has no newline after it: the file ends inside the scan
            truncated += 1
            log.warning("%s:%d: scan %d is cut short (%d of %d point lines); left out", path, first, index,
                        max(len(body) - 1, 0), n)
            break
        for k, pl in enumerate(body):
            if pl.count(";") != 8 or pl.count(",") != 2:
                raise _fail(path, start + k + 1, f"malformed point line {pl[:80]!r}")
        scans.append((
            index, _scan_time(path, i + 2, vals[0]), _scan_time(path, i + 3, vals[1]),
            _int(path, i + 5, vals[3]),
            n, _utc_time(path, i + 7, vals[5]), _vector(path, i + 8, vals[6]), _vector(path, i + 9, vals[7]),
            _vector(path, i + 10, vals[8]), _int(path, i + 11, vals[9]), _int(path, i + 12, vals[10]),
        ))
        point_lines.extend(body)
        point_line_starts.append(start + 1)
        i = start + n
    table = _parse_points(path, point_lines, point_line_starts, [s[4] for s in scans])
    return _assemble(path, scans, table, truncated)


def _parse_points(path: Path, point_lines: list[str], starts: list[int], counts: list[int]) -> np.ndarray:
    if not point_lines:
        return np.zeros((0, 11))
    text = "\n".join(point_lines).replace(";", " ").replace(",", " ")
    try:
        table = np.array(text.split(), dtype=np.float64).reshape(-1, 11)
    except ValueError:
        line_of = np.repeat(np.asarray(starts), counts) + _ranks(counts)
        for k, pl in enumerate(point_lines):
            try:
                [float(t) for t in pl.replace(";", " ").replace(",", " ").split()]
            except ValueError:
                raise _fail(path, int(line_of[k]), f"bad number in point line {pl[:80]!r}") from None
        raise _fail(path, starts[0], "point lines do not have 11 fields each") from None
    expected_num = _ranks(counts) + 1
    bad = np.nonzero(table[:, 0] != expected_num)[0]
    if len(bad):
        line_of = np.repeat(np.asarray(starts), counts) + _ranks(counts)
        k = bad[0]
        raise _fail(path, int(line_of[k]), f"point number {table[k, 0]:g}, expected {expected_num[k]}")
    return table


def _ranks(counts: list[int]) -> np.ndarray:
    """0..n-1 within each scan, for all points."""
    counts_a = np.asarray(counts, dtype=np.int64)
    total = int(counts_a.sum())
    firsts = np.repeat(np.cumsum(counts_a) - counts_a, counts_a)
    return np.arange(total, dtype=np.int64) - firsts


def _assemble(path: Path, scans: list[tuple], table: np.ndarray, truncated: int) -> LidarLog:
    s = len(scans)
    n_points = np.array([sc[4] for sc in scans], dtype=np.int64)
    first = np.cumsum(n_points) - n_points
    return LidarLog(
        source=str(path), format="text",
        scan_index=np.array([sc[0] for sc in scans], dtype=np.int64),
        scan_number=np.full(s, -1, dtype=np.int64),
        scan_flags=np.array([sc[3] for sc in scans], dtype=np.int64),
        start_time=np.array([sc[1] for sc in scans], dtype=np.float64),
        end_time=np.array([sc[2] for sc in scans], dtype=np.float64),
        first_point=first.astype(np.int64), n_points=n_points,
        pose_time=np.array([sc[5] for sc in scans], dtype=np.float64),
        euler=np.array([sc[6] for sc in scans], dtype=np.float64).reshape(s, 3),
        lla=np.array([sc[7] for sc in scans], dtype=np.float64).reshape(s, 3),
        vel=np.array([sc[8] for sc in scans], dtype=np.float64).reshape(s, 3),
        status=np.array([sc[9] for sc in scans], dtype=np.int64),
        valid=np.array([sc[10] for sc in scans], dtype=np.int64),
        xyz=table[:, 1:4].copy(),
        echo_width=table[:, 4].copy(),
        flags=table[:, 5].astype(np.int64),
        layer=table[:, 6].astype(np.int64),
        echo=table[:, 7].astype(np.int64),
        offset_us=table[:, 8].astype(np.int64),
        point_valid=table[:, 9].astype(np.int64),
        point_scan=point_scan_index(n_points),
        truncated_scans=truncated,
    )
