"""A logged scan record → the bus's :class:`bbcs.contracts.lidar.LidarScan` (pure; numpy, no per-point Python)."""

from __future__ import annotations

import time

from bbcs.contracts.geo import Attitude, GeoPoint
from bbcs.contracts.lidar import LidarScan, ScannerMounting, pack_points
from modules.lidar_logger.georef import Mounting
from modules.lidar_logger.logdata import ScanRecord


def to_lidar_scan(record: ScanRecord, mounting: Mounting, stamp: float | None = None) -> LidarScan:
    """The scan's points in the scanner frame (metres), with the mounting and the pose attached to it."""
    scan, pose = record.scan, record.pose
    points, xyz, layer = pack_points(scan.cartesian(), scan.layer)
    roll, pitch, yaw = pose.euler
    lat, lon, alt = pose.lla
    return LidarScan(
        stamp=time.time() if stamp is None else stamp, scan_number=scan.scan_number, index=record.index,
        points=points, xyz=xyz, layer=layer,
        mounting=ScannerMounting(roll=mounting.roll, pitch=mounting.pitch, yaw=mounting.yaw,
                                 x=mounting.x, y=mounting.y, z=mounting.z),
        pose_valid=pose.valid == 1, position=GeoPoint(lat=lat, lon=lon, alt=alt),
        attitude=Attitude(roll=roll, pitch=pitch, yaw=yaw))
