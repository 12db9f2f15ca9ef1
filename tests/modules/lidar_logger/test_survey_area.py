"""The survey side of ``cromat lidar dtm``: coverage over the surveyed polygon, poses interpolated at every
point's time on an aircraft whose attitude moves, scans left out in turns, the simulator's terrain check."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from bbcs.contracts.vehicle_truth import VehicleTruth
from bbcs.geodesy import LocalFrame
from modules.lidar_logger import cli
from modules.lidar_logger.area import AreaError, load_polygon, polygon_enu
from modules.lidar_logger.dtm import attitude_rates, ground_candidates
from modules.lidar_logger.georef import Mounting, georeference
from modules.lidar_logger.logformats import load_log
from modules.lidar_logger.sim import LdmrsOptions, World
from modules.lidar_logger.sim.follow import FollowedFlight
from modules.lidar_logger.sim.survey_flight import flight_scans, write_run
from modules.lidar_logger.sim.terrain_check import dtm_error

HOME = (37.4117, -6.0025, 12.0)
FRAME = LocalFrame(*HOME)
"""The DSP simulator's frame at home (bbcs.geodesy), in which these flights are written."""


def wobbling_world() -> World:
    """A helicopter-like flight: 5 m/s north-east at 25 m, roll and pitch oscillating ±4° at 1.5 Hz."""
    world = World(origin_lla=HOME, gps_fix_at=0.0, xkf_valid_at=0.0)
    flight = FollowedFlight(HOME)
    for k in range(1500):  # 30 s at 50 Hz
        t = k * 0.02
        n = e = 3.5 * t
        flight.add(VehicleTruth(
            seq=k, time_s=t, time_scale=1.0, home=HOME, lat=FRAME.to_geo(e, n)[0],
            lon=FRAME.to_geo(e, n)[1], alt=HOME[2] + 25.0,
            vel_neu=(3.5, 3.5, 0.0), roll=4.0 * math.sin(2 * math.pi * 1.5 * t),
            pitch=-3.0 + 4.0 * math.cos(2 * math.pi * 1.5 * t), heading=45.0))
    world.flight = flight
    return world


@pytest.fixture(scope="module")
def wobbly_scans() -> tuple[World, list]:
    """The wobbling flight's scans from 2 s to 20 s, each with its true pose: cast once (seconds of ray casting) for
    the tests that attach to them the pose a logger would have."""
    world = wobbling_world()
    return world, list(flight_scans(world, LdmrsOptions(return_fraction=0.5, seed=5), t_start=2.0, t_end=20.0))


@pytest.fixture(scope="module")
def wobbly_log(wobbly_scans, tmp_path_factory):
    """Scans whose pose is the one a logger polling every 60 ms would attach: up to ~100 ms old."""
    world, scans = wobbly_scans
    records = []
    for r in scans:
        t_end = r.scan.end_time - world.utc_start
        t_pose = math.floor(t_end / 0.06) * 0.06 - 0.03
        records.append(dataclasses.replace(r, pose=world.true_pose(t_pose)))
    folder = write_run(tmp_path_factory.mktemp("wobbly") / "Scan_wobbly", world, records)
    return world, folder


def _errors(world: World, log, **kw) -> np.ndarray:
    """Vertical errors of the points measured before the newest pose (after it, any method extrapolates)."""
    g = georeference(log, Mounting(), origin_lla=np.array(HOME), select=ground_candidates(log.flags),
                     time_align=True, **kw)
    i = g.point_index
    tau = log.start_time[log.point_scan[i]] + log.offset_us[i] * 1e-6
    inside = tau <= np.nanmax(log.pose_time)
    assert inside.mean() > 0.95
    return (g.enu[:, 2] - world.terrain.height(g.enu[:, 0], g.enu[:, 1]))[inside]


def test_interpolated_poses_follow_the_attitude_between_poses(wobbly_log) -> None:
    world, folder = wobbly_log
    log = load_log(folder)
    scan_pose = _errors(world, log)
    interpolated = _errors(world, log, interpolate_poses=True)
    rms = lambda e: float(np.sqrt(np.mean(e**2)))  # noqa: E731
    # the scan's own pose is up to ~100 ms old while the attitude moves at up to 38°/s: decimetres off
    assert rms(scan_pose) > 0.1
    # interpolation between logged poses 60-120 ms apart: a sine's chord error (up to ~0.6° at 120 ms)
    assert rms(interpolated) < 0.3 * rms(scan_pose) and rms(interpolated) < 0.1
    assert np.abs(interpolated).max() < 0.6 * np.abs(scan_pose).max()


def test_points_in_a_gap_of_the_pose_track_are_left_out_and_counted(wobbly_scans, tmp_path) -> None:
    """A logger starved of CPU for two seconds attached one old pose to every scan of that time: the points
    measured then are left out (counted), not put metres off by two seconds of extrapolation, and the rest of
    the flight keeps its accuracy. (The wobbling flight's scans ending before 14 s.)"""
    world, scans = wobbly_scans
    records = []
    for r in scans:
        t_end = r.scan.end_time - world.utc_start
        if t_end >= 14.0:
            break
        t_pose = 7.97 if 8.0 <= t_end < 10.0 else math.floor(t_end / 0.06) * 0.06 - 0.03
        records.append(dataclasses.replace(r, pose=world.true_pose(t_pose)))
    log = load_log(write_run(tmp_path / "Scan_gap", world, records))
    g = georeference(log, Mounting(), origin_lla=np.array(HOME), select=ground_candidates(log.flags),
                     time_align=True, interpolate_poses=True)
    tau = log.start_time[log.point_scan[g.point_index]] + log.offset_us[g.point_index] * 1e-6
    t0 = world.utc_start
    assert g.skipped_pose_gap > 0.1 * len(g.point_index)
    assert not np.any((tau > t0 + 8.2) & (tau < t0 + 9.8)), "a point inside the gap was georeferenced"
    err = g.enu[:, 2] - world.terrain.height(g.enu[:, 0], g.enu[:, 1])
    inside = tau <= np.nanmax(log.pose_time)
    assert float(np.sqrt(np.mean(err[inside] ** 2))) < 0.1


def test_interpolation_on_constant_attitude_changes_nothing_measurable(tmp_path) -> None:
    world = World(gps_fix_at=0.0, xkf_valid_at=0.0)
    records = list(flight_scans(world, LdmrsOptions(return_fraction=0.3, seed=2), t_start=5.0, n_scans=40))
    log = load_log(write_run(tmp_path / "Scan_straight", world, records))
    a = georeference(log, world.mounting, origin_lla=np.array(world.origin_lla), time_align=True).enu
    b = georeference(log, world.mounting, origin_lla=np.array(world.origin_lla), time_align=True,
                     interpolate_poses=True).enu
    assert np.abs(a - b).max() < 1e-3


def test_attitude_rates_from_consecutive_poses() -> None:
    t = np.array([0.0, 0.0, 0.1, 0.2, 0.2, 0.3, np.nan])
    euler = np.array([[0, 0, 179.0], [0, 0, 179.0], [0, 0, -179.0], [0, 1.0, -179.0], [0, 1.0, -179.0],
                      [0, 1.0, -179.0], [0, 0, 0]])
    rates = attitude_rates(t, euler)
    assert rates[0] == pytest.approx(20.0)  # 2° across the yaw wrap in 0.1 s
    assert rates[2] == pytest.approx(20.0) and rates[3] == pytest.approx(10.0) and rates[5] == pytest.approx(0.0)
    assert rates[6] == np.inf


def _polygon_file(tmp_path, world: World, east_north: list[tuple[float, float]]):
    lla = world.terrain_to_lla(np.array([[e, n, 0.0] for e, n in east_north]))
    ring = [[float(lon), float(lat)] for lat, lon, _ in lla]
    path = tmp_path / "area.geojson"
    path.write_text(json.dumps({"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [ring]}}))
    return path


def test_dtm_reports_coverage_inside_the_polygon_and_the_terrain_check_agrees(wobbly_log, tmp_path, capsys) -> None:
    world, folder = wobbly_log
    area = _polygon_file(tmp_path, world, [(10.0, 0.0), (60.0, 40.0), (40.0, 70.0), (-5.0, 20.0)])
    tif = tmp_path / "dtm.tif"
    assert cli.main(["dtm", str(folder), "--cell", "2", "--polygon", str(area), "--origin", *map(str, HOME),
                     "--time-align", "on", "--interpolate-poses", "--max-turn-rate", "200", "--out", str(tif),
                     "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    inside = report["polygon"]
    assert 0 < inside["cells"] < report["cells"] and inside["cells_with_data"] <= inside["cells"]
    assert inside["coverage_pct"] > 90 and report["scans_left_out_turning"] == 0
    err = dtm_error(tif, polygon=[tuple(v) for v in load_polygon(area)], terrain_origin=HOME)
    assert err["cells"] == inside["cells_with_data"]
    assert err["rms_m"] < 0.05
    # a turn-rate limit inside the wobble's rates (33-37°/s between poses) leaves the fastest-moving scans out
    assert cli.main(["dtm", str(folder), "--cell", "2", "--max-turn-rate", "35.5", "--out", str(tmp_path / "b.tif"),
                     "--json"]) == 0
    limited = json.loads(capsys.readouterr().out)
    assert 0 < limited["scans_left_out_turning"] < load_log(folder).n_scans
    assert limited["points"] < report["points"]


def test_a_bad_polygon_file_is_refused_naming_it(wobbly_log, tmp_path, capsys) -> None:
    _, folder = wobbly_log
    bad = tmp_path / "line.geojson"
    bad.write_text(json.dumps({"type": "LineString", "coordinates": [[0, 0], [1, 1]]}))
    out = tmp_path / "never.tif"
    assert cli.main(["dtm", str(folder), "--cell", "2", "--polygon", str(bad), "--out", str(out)]) == 1
    assert "line.geojson: GeoJSON 'LineString' is not a Polygon" in capsys.readouterr().err and not out.exists()
    with pytest.raises(AreaError, match="3 vertices"):
        load_polygon(_write(tmp_path / "two.geojson", {"type": "Polygon", "coordinates": [[[0, 0], [1, 1]]]}))
    with pytest.raises(AreaError, match="valid"):
        load_polygon(_write(tmp_path / "far.geojson",
                            {"type": "Polygon", "coordinates": [[[0, 0], [1, 95], [2, 0]]]}))


def test_polygon_vertices_land_in_the_enu_frame() -> None:
    world = World(origin_lla=HOME)
    pts = np.array([[100.0, 50.0, 0.0], [-30.0, 200.0, 0.0]])
    lla = world.terrain_to_lla(pts)
    assert polygon_enu(lla[:, :2], np.array(HOME)) == pytest.approx(pts[:, :2], abs=0.01)


def _write(path, doc):
    path.write_text(json.dumps(doc))
    return path
