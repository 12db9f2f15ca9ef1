import numpy as np
import pytest

from modules.vision.geodesy import LocalFrame
from modules.vision.pose import AircraftPose
from modules.vision.trajectory import TrajectoryConfig, plan_trajectory

AIRCRAFT = AircraftPose(lat=37.41, lon=-6.0, alt=80.0, yaw=30.0)
FRAME = LocalFrame(AIRCRAFT.lat, AIRCRAFT.lon, 0.0)


def target_at(east, north, alt=0.0):
    lat, lon, _ = FRAME.to_lla([east, north, 0.0])
    return float(lat), float(lon), alt


def local(waypoints):
    return FRAME.to_enu(waypoints[:, 0], waypoints[:, 1], waypoints[:, 2])


def test_evenly_spaced_toward_and_ending_over_the_target():
    wps = plan_trajectory(AIRCRAFT, target_at(60.0, 90.0), TrajectoryConfig(n_points=3))
    assert wps.shape == (3, 3) and wps.dtype == np.float64
    np.testing.assert_allclose(local(wps), [[20, 30, 80], [40, 60, 80], [60, 90, 80]], atol=1e-6)


def test_altitude_keeps_clearance_above_the_target_and_never_descends():
    high_target = target_at(10.0, 10.0, alt=75.0)
    wps = plan_trajectory(AIRCRAFT, high_target, TrajectoryConfig(min_height_m=20.0))
    assert np.all(wps[:, 2] == 95.0)
    wps = plan_trajectory(AIRCRAFT, target_at(10.0, 10.0, alt=-50.0), TrajectoryConfig(min_height_m=20.0))
    assert np.all(wps[:, 2] == 80.0)


def test_already_over_the_target_gives_one_waypoint():
    wps = plan_trajectory(AIRCRAFT, target_at(1.0, -1.0), TrajectoryConfig(arrive_radius_m=2.0))
    assert wps.shape == (1, 3)
    np.testing.assert_allclose(local(wps)[0, :2], [1.0, -1.0], atol=1e-6)


def test_overfly_adds_a_point_beyond_the_target():
    wps = plan_trajectory(AIRCRAFT, target_at(0.0, 50.0), TrajectoryConfig(n_points=2, overfly_m=30.0))
    np.testing.assert_allclose(local(wps)[:, :2], [[0, 25], [0, 50], [0, 80]], atol=1e-6)


def test_waypoints_stay_in_range_across_the_antimeridian():
    aircraft = AircraftPose(lat=-16.5, lon=179.9995, alt=50.0)
    frame = LocalFrame(aircraft.lat, aircraft.lon, 0.0)
    lat, lon, _ = frame.to_lla([200.0, 0.0, 0.0])  # 200 m east: across 180
    wps = plan_trajectory(aircraft, (float(lat), float(lon), 0.0), TrajectoryConfig(n_points=4))
    assert np.all((wps[:, 0] >= -90) & (wps[:, 0] <= 90))
    assert np.all((wps[:, 1] >= -180) & (wps[:, 1] <= 180))
    assert wps[0, 1] > 0 and wps[-1, 1] < 0
    np.testing.assert_allclose(frame.to_enu(*wps.T)[:, 0], [50, 100, 150, 200], atol=1e-6)


def test_bad_target_and_config_are_refused():
    with pytest.raises(ValueError, match="latitude"):
        plan_trajectory(AIRCRAFT, (95.0, 0.0, 0.0), TrajectoryConfig())
    for kwargs in (dict(n_points=0), dict(min_height_m=-1.0), dict(overfly_m=float("nan"))):
        with pytest.raises(ValueError):
            TrajectoryConfig(**kwargs)
