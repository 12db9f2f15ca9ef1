"""Lidar scans on the bus: one struct per scan, its points packed as little-endian buffers, never lists.

The lidar logger publishes every scan it receives on its ``scan`` slot (unsafe state: a lost scan is not
resent, the logger's own files stay the record). ``cromat record`` records it and ``cromat foxglove`` shows it as
a point cloud in the 3D panel. Points are in the scanner's frame (DIN 70000: x out of the window, y left, z up),
in metres; ``mounting`` places the scanner in the vehicle's body frame and ``position``/``attitude`` the vehicle
in the world when the scan arrived, so a reader can georeference without the logger's files.

Decoding is validating: counts, buffer lengths, layers and coordinates are checked in ``__post_init__`` (a
damaged scan raises ``msgspec.ValidationError`` and is dropped whole, no point of it used).
"""

from __future__ import annotations

from typing import Annotated

import msgspec
import numpy as np

from bbcs.contracts.geo import Attitude, GeoPoint

MAX_POINTS = 65_536
"""More points than an LD-MRS scan can hold (its point count is a 16-bit field)."""
MAX_RANGE_M = 700.0
"""Any coordinate farther than this from the scanner is damage (the LD-MRS distance field ends at 655.35 m)."""
MAX_LAYER = 3
XYZ_DTYPE = np.dtype("<f4")
"""Element type of ``xyz``: float32 x, y, z per point, 12 bytes a point."""
POINT_BYTES = 3 * XYZ_DTYPE.itemsize


class ScannerMounting(msgspec.Struct, frozen=True, kw_only=True):
    """Scanner in the body frame: p_body = Rz(yaw) Ry(pitch) Rx(roll) · p_scanner + (x, y, z); degrees, metres."""

    roll: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = 0.0
    pitch: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = 0.0
    yaw: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = 0.0
    x: Annotated[float, msgspec.Meta(ge=-50.0, le=50.0)] = 0.0
    y: Annotated[float, msgspec.Meta(ge=-50.0, le=50.0)] = 0.0
    z: Annotated[float, msgspec.Meta(ge=-50.0, le=50.0)] = 0.0


class LidarScan(msgspec.Struct, frozen=True, kw_only=True):
    """One scan: ``points`` points, ``xyz`` their coordinates (``XYZ_DTYPE``, 12 bytes each), ``layer`` one byte
    each (0 lowest .. 3)."""

    stamp: float
    """POSIX seconds at which the scan arrived (the pose is the newest one at that time)."""
    scan_number: Annotated[int, msgspec.Meta(ge=0, le=65535)]
    """The scanner's own scan counter."""
    index: Annotated[int, msgspec.Meta(ge=1)]
    """Scans received in this run, from 1 (the logger's record index: the same scan in its files)."""
    points: Annotated[int, msgspec.Meta(ge=0, le=MAX_POINTS)]
    xyz: bytes
    layer: bytes
    mounting: ScannerMounting = msgspec.field(default_factory=ScannerMounting)
    pose_valid: bool = False
    """The pose is a valid INS solution (status self-test, GPS fix, XKF valid) and not stale."""
    position: GeoPoint | None = None
    attitude: Attitude | None = None

    def __post_init__(self) -> None:
        if len(self.xyz) != self.points * POINT_BYTES:
            raise ValueError(f"xyz holds {len(self.xyz)} bytes, not {POINT_BYTES} × {self.points} points")
        if len(self.layer) != self.points:
            raise ValueError(f"layer holds {len(self.layer)} bytes, not one per point ({self.points})")
        if self.points:
            if max(self.layer) > MAX_LAYER:
                raise ValueError(f"a layer above {MAX_LAYER}")
            xyz = np.frombuffer(self.xyz, dtype=XYZ_DTYPE)
            if not np.isfinite(xyz).all() or float(np.abs(xyz).max()) > MAX_RANGE_M:
                raise ValueError(f"a coordinate not finite or beyond {MAX_RANGE_M:g} m")

    def xyz_array(self) -> np.ndarray:
        """The points as an (N, 3) float32 array (a read-only view on ``xyz``)."""
        return np.frombuffer(self.xyz, dtype=XYZ_DTYPE).reshape(self.points, 3)

    def layer_array(self) -> np.ndarray:
        return np.frombuffer(self.layer, dtype=np.uint8)


def pack_points(xyz: np.ndarray, layer: np.ndarray) -> tuple[int, bytes, bytes]:
    """(points, xyz bytes, layer bytes) of an (N, 3) coordinate array and N layers, in the contract's types."""
    coords = np.ascontiguousarray(xyz, dtype=XYZ_DTYPE).reshape(-1, 3)
    layers = np.ascontiguousarray(layer, dtype=np.uint8).reshape(-1)
    if len(coords) != len(layers):
        raise ValueError(f"{len(coords)} points but {len(layers)} layers")
    return len(coords), coords.tobytes(), layers.tobytes()
