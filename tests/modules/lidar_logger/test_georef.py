"""Georeferencing on hand-made logs whose answers are known exactly."""

from __future__ import annotations

import numpy as np
import pytest

from modules.lidar_logger.geodesy import ecef_from_enu, ecef_to_lla, lla_to_ecef
from modules.lidar_logger.georef import GeorefError, Mounting, clocks_synchronised, georeference
from modules.lidar_logger.logdata import LidarLog, point_scan_index

ORIGIN = np.array([37.4261, -6.0032, 150.0])
T0 = 1284103855.0


def lla_at(enu: list[float]) -> np.ndarray:
    """Geodetic position of a point given in the ENU frame at ORIGIN."""
    return ecef_to_lla(
        lla_to_ecef(ORIGIN) + ecef_from_enu(ORIGIN[0], ORIGIN[1]) @ np.asarray(enu, dtype=float)
    )


def make_log(scans: list[dict], points: list[list[tuple]]) -> LidarLog:
    """Scans: dicts with euler, lla, vel, valid, dt_pose (pose UTC - scan start).
    Points, per scan: (xyz, valid[, offset_us])."""
    n_points = np.array([len(p) for p in points])
    flat = [p for ps in points for p in ps]
    s = len(scans)
    start = T0 + 0.08 * np.arange(s)
    return LidarLog(
        source="test",
        format="test",
        scan_index=np.arange(1, s + 1),
        scan_number=np.arange(s),
        scan_flags=np.zeros(s, int),
        start_time=start,
        end_time=start + 0.0222,
        first_point=np.cumsum(n_points) - n_points,
        n_points=n_points,
        pose_time=start + np.array([sc.get("dt_pose", 0.0) for sc in scans]),
        euler=np.array([sc.get("euler", (0, 0, 0)) for sc in scans], dtype=float),
        lla=np.array([sc.get("lla", ORIGIN) for sc in scans], dtype=float),
        vel=np.array([sc.get("vel", (0, 0, 0)) for sc in scans], dtype=float),
        status=np.array([7 if sc.get("valid", 1) else 5 for sc in scans]),
        valid=np.array([sc.get("valid", 1) for sc in scans]),
        xyz=np.array([p[0] for p in flat], dtype=float).reshape(-1, 3),
        echo_width=np.ones(len(flat)),
        flags=np.array([0 if p[1] else 4 for p in flat]),
        layer=np.zeros(len(flat), int),
        echo=np.zeros(len(flat), int),
        offset_us=np.array([p[2] if len(p) > 2 else 0 for p in flat], dtype=np.int64),
        point_valid=np.array([int(p[1]) for p in flat]),
        point_scan=point_scan_index(n_points),
    )


def test_a_level_scanner_looking_down() -> None:
    log = make_log([{}], [[((10.0, 0, 0), True), ((10.0, 2.0, 0), True)]])
    r = georeference(log)
    assert r.origin_lla.tolist() == ORIGIN.tolist()
    assert r.enu[0] == pytest.approx([0, 0, -10], abs=1e-9)
    assert r.enu[1] == pytest.approx([-2, 0, -10], abs=1e-9), "scanner y = body left = west"


def test_heading_roll_and_mounting_offsets() -> None:
    m = Mounting(roll=0, pitch=90, yaw=0, x=0.5, y=0, z=-0.2)
    log = make_log(
        [{"euler": (0, 0, 90.0)}, {"euler": (30.0, 0, 0)}], [[((10.0, 0, 0), True)], [((10.0, 0, 0), True)]]
    )
    r = georeference(log, m)
    # yaw 90: body x points west; the mounting offset 0.5 m forward is 0.5 m west
    assert r.enu[0] == pytest.approx([-0.5, 0, -10.2], abs=1e-9)
    # roll 30 (left wing up, banking right): the belly axis swings left, i.e. west when heading north
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    assert r.enu[1] == pytest.approx([-10.2 * s, 0.5, -10.2 * c], abs=1e-9)


def test_positions_far_from_the_origin_use_exact_geodesy() -> None:
    far = [2000.0, -1500.0, 30.0]
    log = make_log([{}, {"lla": lla_at(far)}], [[((10.0, 0, 0), True)], [((10.0, 0, 0), True)]])
    r = georeference(log)
    # the local vertical at 2.5 km away is tilted by 2500/6.4e6 rad: exact result via ECEF
    down_there = ecef_from_enu(*lla_at(far)[:2])[:, 2] * -10.0
    expect = ecef_from_enu(ORIGIN[0], ORIGIN[1]).T @ (
        lla_to_ecef(lla_at(far)) + down_there - lla_to_ecef(ORIGIN)
    )
    assert r.enu[1] == pytest.approx(expect, abs=1e-6)
    assert abs(r.enu[1][0] - 2000) < 0.01 and abs(r.enu[1][2] - 20.0) < 0.01


def test_antenna_positions_are_moved_back_to_the_imu() -> None:
    log = make_log([{"euler": (0, 0, 90.0)}], [[((10.0, 0, 0), True)]])
    r = georeference(log, lever_arm=(-0.34, 0.01, 0.26), position_ref="antenna")
    # body (-0.34, 0.01, 0.26) with yaw 90 is NWU (-0.01, -0.34, 0.26) -> ENU (0.34, -0.01, 0.26); subtract it
    assert r.enu[0] == pytest.approx([-0.34, 0.01, -10.26], abs=1e-9)
    with pytest.raises(GeorefError):
        georeference(log, position_ref="gps")


def test_time_alignment_moves_the_imu_along_its_velocity() -> None:
    log = make_log(
        [{"vel": (10.0, 0, 0), "dt_pose": 0.05}], [[((10.0, 0, 0), True, 0), ((10.0, 0, 0), True, 22200)]]
    )
    assert clocks_synchronised(log)
    r = georeference(log)
    assert r.time_aligned
    # NWU velocity 10 m/s north; point times -0.05 s and -0.0278 s relative to the pose
    assert r.enu[0] == pytest.approx([0, -0.5, -10], abs=1e-6)
    assert r.enu[1] == pytest.approx([0, -0.278, -10], abs=1e-6)
    off = georeference(log, time_align=False)
    assert not off.time_aligned and off.enu[0] == pytest.approx([0, 0, -10], abs=1e-9)


def test_unsynchronised_clocks_are_not_aligned_automatically() -> None:
    log = make_log([{"vel": (10.0, 0, 0), "dt_pose": 3600.0}], [[((10.0, 0, 0), True)]])
    assert not clocks_synchronised(log)
    assert not georeference(log).time_aligned


def test_flagged_points_and_invalid_poses_are_left_out_and_counted() -> None:
    log = make_log(
        [{}, {"valid": 0}, {}],
        [[((10.0, 0, 0), True), ((3.0, 0, 0), False)], [((10.0, 0, 0), True)], [((9.0, 0, 0), True)]],
    )
    r = georeference(log)
    assert r.point_index.tolist() == [0, 3]
    assert r.skipped_invalid_points == 1 and r.skipped_invalid_pose == 1


def test_no_valid_pose_is_an_error() -> None:
    with pytest.raises(GeorefError, match="no scan has a valid pose"):
        georeference(make_log([{"valid": 0}], [[((10.0, 0, 0), True)]]))
