"""What a log holds, in memory: one scan record on the way to disk, and a whole log loaded as numpy arrays.

Both log formats load into the same ``LidarLog`` so reading, exporting and georeferencing do not care which
one was written. Times are POSIX seconds (UTC) as float64; angles in degrees; lengths in metres.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from modules.lidar_logger.ldmrs_scan import Scan
from modules.lidar_logger.mtdata import Pose


class LogFormatError(ValueError):
    """A log file that is not what it should be; the message names the file and line (or byte offset)."""


@dataclass(frozen=True, slots=True)
class ScanRecord:
    """A scan with the pose that was newest when it arrived; ``index`` counts scans received, from 1."""

    index: int
    scan: Scan
    pose: Pose


@dataclass
class LidarLog:
    source: str
    format: str
    # per scan (S)
    scan_index: np.ndarray
    scan_number: np.ndarray
    """Wire scan number; -1 when loaded from the text log, which does not carry it."""
    scan_flags: np.ndarray
    start_time: np.ndarray
    end_time: np.ndarray
    first_point: np.ndarray
    n_points: np.ndarray
    pose_time: np.ndarray
    """UTC of the attached MTi-G sample; NaN when its date was not valid."""
    euler: np.ndarray
    lla: np.ndarray
    vel: np.ndarray
    status: np.ndarray
    valid: np.ndarray
    # per point (P)
    xyz: np.ndarray
    echo_width: np.ndarray
    flags: np.ndarray
    """Seed-enum flags (see ``flags.py``)."""
    layer: np.ndarray
    echo: np.ndarray
    offset_us: np.ndarray
    point_valid: np.ndarray
    point_scan: np.ndarray
    """Index into the per-scan arrays of the scan each point belongs to."""
    truncated_scans: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def n_scans(self) -> int:
        return len(self.scan_index)

    @property
    def total_points(self) -> int:
        return len(self.xyz)

    def summary(self) -> dict[str, object]:
        finite = np.isfinite(self.pose_time)
        return {
            "source": self.source,
            "format": self.format,
            "scans": self.n_scans,
            "points": self.total_points,
            "valid_points": int(self.point_valid.sum()),
            "scans_with_valid_pose": int((self.valid == 1).sum()),
            "first_scan_start_utc": float(self.start_time[0]) if self.n_scans else None,
            "last_scan_end_utc": float(self.end_time[-1]) if self.n_scans else None,
            "first_pose_utc": float(self.pose_time[finite][0]) if finite.any() else None,
            "scan_index_gaps": int(np.count_nonzero(np.diff(self.scan_index) != 1)) if self.n_scans else 0,
            "truncated_scans": self.truncated_scans,
        }

    def save_npz(self, path: str | os.PathLike[str]) -> Path:
        """Every array under its field name; plain ``np.load`` reads it (docs/lidar_logger.md lists them)."""
        path = Path(path)
        arrays = {name: getattr(self, name) for name in _ARRAY_FIELDS}
        np.savez_compressed(path, **arrays)
        return path


_ARRAY_FIELDS = (
    "scan_index", "scan_number", "scan_flags", "start_time", "end_time", "first_point", "n_points",
    "pose_time", "euler", "lla", "vel", "status", "valid",
    "xyz", "echo_width", "flags", "layer", "echo", "offset_us", "point_valid", "point_scan",
)


def point_scan_index(n_points: np.ndarray) -> np.ndarray:
    """For each point, the index of its scan (scans given by their point counts)."""
    return np.repeat(np.arange(len(n_points), dtype=np.int64), np.asarray(n_points, dtype=np.int64))
