"""Geolocation against analytic cases and the inverse (pointing angles).

Conventions under test: tilt is the elevation (-90 = nadir), pan is clockwise from the nose/heading; a
stabilised mount ignores roll and pitch, a body-fixed mount follows them.
"""

import math

import numpy as np
import pytest

from modules.vision.geometry import (
    CameraModel,
    enu_from_optical,
    enu_to_pixel,
    intersect_ground,
    pixel_to_enu,
    pointing_angles,
)
from modules.vision.pose import AircraftPose, Gimbal

STAB = CameraModel()
BODY = CameraModel(stabilised=False)
CENTRE = STAB.centre
H = 100.0
ORIGIN = np.array([0.0, 0.0, H])


def pose(roll=0.0, pitch=0.0, yaw=0.0, alt=H):
    return AircraftPose(lat=37.4, lon=-6.0, alt=alt, roll=roll, pitch=pitch, yaw=yaw)


def ground(p, g, uv=CENTRE, ground_up=0.0, cam=STAB):
    return pixel_to_enu(cam, p, g, ORIGIN, uv, ground_up)


@pytest.mark.parametrize("cam", [STAB, BODY])
@pytest.mark.parametrize(("yaw", "pan"), [(0, 0), (73, -120), (-150, 45)])
def test_nadir_target_is_directly_below(yaw, pan, cam):
    point = ground(pose(yaw=yaw), Gimbal(pan=pan, tilt=-90.0), cam=cam)
    np.testing.assert_allclose(point, [0.0, 0.0, 0.0], atol=1e-9)


@pytest.mark.parametrize("cam", [STAB, BODY])
@pytest.mark.parametrize(
    ("yaw", "pan", "east", "north"),
    [
        (0, 0, 0, H),
        (90, 0, H, 0),
        (0, 90, H, 0),
        (0, -90, -H, 0),
        (180, 0, 0, -H),
        (45, 45, H, 0),
        (-30, 120, H, 0),
        (-170, -100, H, 0),
        (-170, -10, 0, -H),
    ],
)
def test_45_degree_tilt_puts_target_at_ground_distance_equal_to_altitude(yaw, pan, east, north, cam):
    point = ground(pose(yaw=yaw), Gimbal(pan=pan, tilt=-45.0), cam=cam)
    np.testing.assert_allclose(point, [east, north, 0.0], atol=1e-9)


def test_45_degree_tilt_any_heading():
    for yaw, pan in [(17.0, 11.0), (-100.0, 33.0), (170.0, 179.0)]:
        point = ground(pose(yaw=yaw), Gimbal(pan=pan, tilt=-45.0))
        bearing = math.radians(yaw + pan)
        np.testing.assert_allclose(point[:2], [H * math.sin(bearing), H * math.cos(bearing)], atol=1e-9)


def test_body_mount_roll_adds_depression_when_looking_right():
    # Right wing down 10 deg, camera looking right (pan 90) 45 deg below the body plane -> 55 deg depression.
    point = ground(pose(roll=10.0), Gimbal(pan=90.0, tilt=-45.0), cam=BODY)
    assert point[0] == pytest.approx(H / math.tan(math.radians(55.0)), abs=1e-9)
    assert point[1] == pytest.approx(0.0, abs=1e-9)


def test_body_mount_nose_up_pitch_raises_a_forward_looking_camera():
    point = ground(pose(pitch=10.0), Gimbal(pan=0.0, tilt=-45.0), cam=BODY)
    assert point[1] == pytest.approx(H / math.tan(math.radians(35.0)), abs=1e-9)


def test_stabilised_mount_ignores_roll_and_pitch():
    level = ground(pose(yaw=30.0), Gimbal(pan=20.0, tilt=-40.0))
    for roll, pitch in [(10.0, 0.0), (0.0, -15.0), (-20.0, 12.0)]:
        tilted = ground(pose(roll=roll, pitch=pitch, yaw=30.0), Gimbal(pan=20.0, tilt=-40.0))
        np.testing.assert_allclose(tilted, level, atol=1e-9)


def test_image_axes_at_nadir_heading_north_are_east_right_north_up():
    f = STAB.focal_px
    a = math.radians(10.0)
    nadir = Gimbal(pan=0.0, tilt=-90.0)
    right = ground(pose(), nadir, uv=(CENTRE[0] + f * math.tan(a), CENTRE[1]))
    up = ground(pose(), nadir, uv=(CENTRE[0], CENTRE[1] - f * math.tan(a)))
    np.testing.assert_allclose(right, [H * math.tan(a), 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(up, [0.0, H * math.tan(a), 0.0], atol=1e-9)


def test_ground_altitude_shifts_the_plane():
    point = ground(pose(), Gimbal(pan=0.0, tilt=-45.0), ground_up=40.0)
    np.testing.assert_allclose(point, [0.0, 60.0, 40.0], atol=1e-9)


def test_rays_above_the_horizon_or_out_of_range_miss():
    assert ground(pose(), Gimbal(pan=0.0, tilt=10.0)) is None
    assert ground(pose(), Gimbal(pan=0.0, tilt=0.0)) is None
    assert pixel_to_enu(STAB, pose(), Gimbal(pan=0.0, tilt=-5.0), ORIGIN, CENTRE, 0.0, max_range=500.0) is None
    below_ground = intersect_ground([0.0, 0.0, -1.0], [0.0, 0.0, -1.0], 0.0)
    assert np.isnan(below_ground).all()


def test_pointing_angles_analytic():
    g = pointing_angles(pose(), ORIGIN, [0.0, H, 0.0])
    assert (g.pan, g.tilt) == pytest.approx((0.0, -45.0))
    g = pointing_angles(pose(yaw=90.0), ORIGIN, [0.0, H, 0.0])  # north is on the left when heading east
    assert (g.pan, g.tilt) == pytest.approx((-90.0, -45.0))
    g = pointing_angles(pose(), ORIGIN, [0.0, 0.0, 0.0])
    assert (g.pan, g.tilt) == pytest.approx((0.0, -90.0))
    g = pointing_angles(pose(), ORIGIN, [0.0, -H, 0.0])  # behind: pan is +/-180
    assert abs(g.pan) == pytest.approx(180.0) and g.tilt == pytest.approx(-45.0)
    g = pointing_angles(pose(roll=10.0), ORIGIN, [H, 0.0, 0.0], stabilised=False)
    assert (g.pan, g.tilt) == pytest.approx((90.0, -35.0))
    g = pointing_angles(pose(roll=10.0), ORIGIN, [H, 0.0, 0.0], stabilised=True)
    assert (g.pan, g.tilt) == pytest.approx((90.0, -45.0))
    with pytest.raises(ValueError, match="coincides"):
        pointing_angles(pose(), ORIGIN, ORIGIN)


def test_same_formula_as_a_heading_and_horizon_gimbal():
    # Independent statement of the stabilised convention: pan = bearing - heading, tilt = elevation.
    rng = np.random.default_rng(3)
    for _ in range(50):
        p = pose(roll=rng.uniform(-20, 20), pitch=rng.uniform(-20, 20), yaw=rng.uniform(-180, 180))
        target = np.array([rng.uniform(-300, 300), rng.uniform(-300, 300), rng.uniform(-50, 50)])
        d = target - ORIGIN
        bearing = math.degrees(math.atan2(d[0], d[1]))
        pan = (bearing - p.yaw + 180.0) % 360.0 - 180.0
        tilt = math.degrees(math.atan2(d[2], math.hypot(d[0], d[1])))
        g = pointing_angles(p, ORIGIN, target)
        assert g.pan == pytest.approx(pan, abs=1e-9) or abs(abs(g.pan) - 180.0) < 1e-9
        assert g.tilt == pytest.approx(tilt, abs=1e-9)


@pytest.mark.parametrize("cam", [STAB, BODY])
def test_geolocate_then_point_round_trip_over_random_poses(cam):
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(300):
        p = pose(roll=rng.uniform(-30, 30), pitch=rng.uniform(-20, 20), yaw=rng.uniform(-180, 180))
        g = Gimbal(pan=rng.uniform(-180, 180), tilt=rng.uniform(-89, -20))
        point = ground(p, g, cam=cam)
        if point is None:
            continue
        back = pointing_angles(p, ORIGIN, point, stabilised=cam.stabilised)
        # The optical axis through the recovered angles must hit the same ground point.
        again = ground(p, back, cam=cam)
        np.testing.assert_allclose(again, point, atol=1e-6 * max(1.0, np.linalg.norm(point)))
        checked += 1
    assert checked > 200


@pytest.mark.parametrize("cam", [STAB, BODY])
def test_project_and_unproject_agree(cam):
    p = pose(roll=5.0, pitch=-3.0, yaw=33.0)
    g = Gimbal(pan=-20.0, tilt=-60.0)
    uv = np.array([[10.0, 20.0], [320.0, 240.0], [630.5, 470.25]])
    points = np.array([ground(p, g, uv=tuple(q), cam=cam) for q in uv])
    np.testing.assert_allclose(enu_to_pixel(cam, p, g, ORIGIN, points), uv, atol=1e-6)
    axis = enu_from_optical(p, g, cam.stabilised) @ [0.0, 0.0, 1.0]
    assert np.isnan(enu_to_pixel(cam, p, g, ORIGIN, ORIGIN - 100.0 * axis)).all()


def test_camera_model_properties_and_validation():
    assert STAB.focal_px == pytest.approx(320.0 / math.tan(math.radians(30.0)))
    assert STAB.centre == (319.5, 239.5)
    assert STAB.vfov_deg == pytest.approx(2 * math.degrees(math.atan(240.0 / STAB.focal_px)))
    x, y = STAB.grid_axes()
    assert x.shape == (640,) and y.shape == (480,)
    np.testing.assert_allclose(STAB.pixel_rays(637.0, 5.0), [x[637], y[5], 1.0], rtol=1e-6)
    assert STAB.contains([[0, 0], [639.4, 479.4], [-0.6, 3], [np.nan, 1]]).tolist() == [True, True, False, False]
    with pytest.raises(ValueError):
        CameraModel(hfov_deg=180.0)
    with pytest.raises(ValueError):
        CameraModel(width=1)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(lat=95.0, lon=0.0, alt=0.0),
        dict(lat=0.0, lon=0.0, alt=0.0, pitch=95.0),
        dict(lat=0.0, lon=0.0, alt=0.0, roll=math.nan),
    ],
)
def test_bad_pose_is_refused(kwargs):
    with pytest.raises(ValueError):
        AircraftPose(**kwargs)


@pytest.mark.parametrize(("pan", "tilt"), [(181.0, 0.0), (0.0, -91.0), (math.nan, 0.0)])
def test_bad_gimbal_is_refused(pan, tilt):
    with pytest.raises(ValueError):
        Gimbal(pan=pan, tilt=tilt)
