"""The simulated camera draws targets where the geometry says they are.

Stated bound: the detected centroid of a rendered target disc (radius >= 5 px in the image) is within 1 px
of the projection of the disc centre (perspective makes a ground disc slightly asymmetric in the image).
"""

import numpy as np
import pytest

from modules.vision.detect import DetectorConfig, detect
from modules.vision.geodesy import LocalFrame
from modules.vision.geometry import CameraModel, enu_to_pixel, pointing_angles
from modules.vision.pose import Gimbal
from modules.vision.scene import CircularTarget, GroundTexture, LinearTarget
from modules.vision.sim_camera import SimulatedCamera

WORLD = LocalFrame(37.41, -6.0, 0.0)


class Clock:
    def __init__(self, now=0.0):
        self.now = now

    def __call__(self):
        return self.now


def make_camera(targets, clock=None, **kwargs):
    clock = clock or Clock()
    return SimulatedCamera(WORLD, targets=targets, clock=clock, epoch=0.0, seed=3, **kwargs)


def position(cam):
    return WORLD.to_enu(cam.pose.lat, cam.pose.lon, cam.pose.alt)


def test_read_before_state_is_none_and_render_needs_state():
    cam = make_camera([])
    assert cam.read() is None
    with pytest.raises(RuntimeError, match="set_state"):
        cam.render(0.0)


@pytest.mark.parametrize(
    ("where", "attitude"),
    [
        ((0.0, 0.0, 80.0), dict()),
        ((-30.0, -60.0, 120.0), dict(roll=4.0, pitch=-2.0, yaw=20.0)),
        ((40.0, 10.0, 60.0), dict(roll=-8.0, pitch=3.0, yaw=-15.0)),
        ((-25.0, 30.0, 30.0), dict(roll=2.0, pitch=5.0, yaw=100.0)),
    ],
)
@pytest.mark.parametrize("stabilised", [True, False])
def test_target_appears_where_projection_says(where, attitude, stabilised):
    target = LinearTarget(start=(12.0, 6.0), radius_m=1.5)
    cam = make_camera([target], noise_sigma=6.0, camera=CameraModel(stabilised=stabilised))
    cam.set_state_enu(where, Gimbal(pan=0.0, tilt=-90.0), **attitude)
    near = cam.targets_enu(0.0)[0] + [3.0, -2.0, 0.0]
    aim = pointing_angles(cam.pose, position(cam), near, stabilised=stabilised)
    cam.set_state(cam.pose, aim)  # look near (not exactly at) the target
    frame = cam.read()
    expected = enu_to_pixel(cam.camera, cam.pose, aim, position(cam), cam.targets_enu(frame.timestamp)[0])
    det = detect(frame.image, DetectorConfig())
    assert det is not None and det.blob.area >= np.pi * 5**2 * 0.8
    assert np.hypot(det.x - expected[0], det.y - expected[1]) < 1.0


def test_pointing_with_the_inverse_angles_centres_the_target():
    clock = Clock(2.0)
    target = CircularTarget(centre=(5.0, 40.0), orbit_m=15.0, period_s=20.0, radius_m=1.5)
    cam = make_camera([target], clock=clock, noise_sigma=6.0)
    cam.set_state_enu((0.0, 0.0, 100.0), Gimbal(pan=0.0, tilt=-45.0), yaw=30.0)
    for now in (2.0, 7.0, 12.5):
        clock.now = now
        aim = pointing_angles(cam.pose, position(cam), cam.targets_enu(now)[0])
        cam.set_state(cam.pose, aim)
        det = detect(cam.read().image, DetectorConfig())
        assert np.hypot(det.x - cam.camera.centre[0], det.y - cam.camera.centre[1]) < 1.0


def test_targets_move_with_the_clock():
    clock = Clock(0.0)
    cam = make_camera([LinearTarget(start=(0.0, 0.0), velocity=(2.0, 0.0), radius_m=1.5)], clock=clock)
    cam.set_state_enu((0.0, 0.0, 60.0), Gimbal(pan=0.0, tilt=-90.0))
    x0 = detect(cam.read().image, DetectorConfig()).x
    clock.now = 2.0  # moved 4 m east = right in the image
    frame = cam.read()
    x1 = detect(frame.image, DetectorConfig()).x
    metres_per_px = 60.0 / cam.camera.focal_px
    assert (x1 - x0) * metres_per_px == pytest.approx(4.0, abs=0.1)
    assert frame.seq == 1 and frame.timestamp == 2.0


def test_rendering_is_deterministic_from_the_seed():
    a = make_camera([LinearTarget(start=(3.0, 3.0))], noise_sigma=5.0)
    b = make_camera([LinearTarget(start=(3.0, 3.0))], noise_sigma=5.0)
    for cam in (a, b):
        cam.set_state_enu((0.0, 0.0, 50.0), Gimbal(pan=20.0, tilt=-60.0), yaw=5.0)
    np.testing.assert_array_equal(a.read().image, b.read().image)
    c = SimulatedCamera(WORLD, texture=GroundTexture(seed=99), clock=Clock(), epoch=0.0)
    c.set_state_enu((0.0, 0.0, 50.0), Gimbal(pan=20.0, tilt=-60.0), yaw=5.0)
    a2 = make_camera([])
    a2.set_state_enu((0.0, 0.0, 50.0), Gimbal(pan=20.0, tilt=-60.0), yaw=5.0)
    assert not np.array_equal(a2.read().image, c.read().image)


def test_target_free_views_give_no_detection():
    cam = make_camera([], noise_sigma=8.0)
    for where, g in [
        ((0, 0, 30), Gimbal(pan=0, tilt=-90)),
        ((50, -20, 150), Gimbal(pan=45, tilt=-20)),
        ((0, 0, 100), Gimbal(pan=0, tilt=30)),
    ]:
        cam.set_state_enu(where, g)
        assert detect(cam.read().image, DetectorConfig()) is None


def test_looking_up_sees_only_sky_and_grey_mode():
    cam = make_camera([], grey=True)
    cam.set_state_enu((0.0, 0.0, 100.0), Gimbal(pan=0.0, tilt=60.0))
    img = cam.read().image
    assert img.shape == (480, 640) and img.dtype == np.uint8
    assert np.ptp(img) == 0
    sky_luma = round(0.299 * 150 + 0.587 * 190 + 0.114 * 230)
    assert abs(int(img[0, 0]) - sky_luma) <= 1


def test_bright_target_is_found_in_grey_frames():
    cam = make_camera(
        [LinearTarget(start=(0.0, 0.0), radius_m=1.5, colour=(255, 255, 255))], grey=True, noise_sigma=6.0
    )
    cam.set_state_enu((0.0, 0.0, 70.0), Gimbal(pan=0.0, tilt=-90.0))
    det = detect(cam.read().image, DetectorConfig(threshold=200))
    assert np.hypot(det.x - 319.5, det.y - 239.5) < 1.0


def test_close_and_argument_checks():
    cam = make_camera([])
    cam.set_state_enu((0.0, 0.0, 50.0), Gimbal(pan=0.0, tilt=-90.0))
    with cam:
        assert cam.read() is not None
    assert cam.closed and cam.read() is None
    cam.close()
    with pytest.raises(ValueError):
        SimulatedCamera(WORLD, noise_sigma=-1.0)


def _texture_per_point(tex, east, north):
    """The texture's definition evaluated at each point (no table): cell and field from the coordinates."""
    ix = np.floor(east / np.float32(tex.cell_m)).astype(np.int32)
    iy = np.floor(north / np.float32(tex.cell_m)).astype(np.int32)
    fx = np.floor(east / np.float32(tex.field_m)).astype(np.int32)
    fy = np.floor(north / np.float32(tex.field_m)).astype(np.int32)
    return tex.cell_colour(ix, iy, fx, fy)


def test_the_texture_table_gives_the_colours_of_the_definition_inside_and_outside_it():
    rng = np.random.default_rng(4)
    tex = GroundTexture(seed=7)
    for span in (300.0, 2000.0):  # within the table's 1 km square, and mostly beyond it
        east = rng.uniform(-span, span, (60, 80)).astype(np.float32)
        north = rng.uniform(-span, span, (60, 80)).astype(np.float32)
        np.testing.assert_array_equal(tex.colour(east, north), _texture_per_point(tex, east, north))
    odd = GroundTexture(field_m=15.0)  # fields not a whole number of cells: no table, the same definition
    east = rng.uniform(-100, 100, (10, 10)).astype(np.float32)
    north = rng.uniform(-100, 100, (10, 10)).astype(np.float32)
    np.testing.assert_array_equal(odd.colour(east, north), _texture_per_point(odd, east, north))


def test_sensor_noise_has_its_sigma_and_differs_frame_to_frame():
    quiet = make_camera([])
    noisy = make_camera([], noise_sigma=6.0)
    for cam in (quiet, noisy):
        cam.set_state_enu((0.0, 0.0, 50.0), Gimbal(pan=0.0, tilt=-90.0))
    clean = quiet.read().image.astype(np.float64)
    first = noisy.read().image.astype(np.float64) - clean
    second = noisy.read().image.astype(np.float64) - clean
    assert abs(first.mean()) < 0.2 and 5.4 < first.std() < 6.6, (first.mean(), first.std())
    assert not np.array_equal(first, second)


def test_the_ground_kept_for_a_still_pose_gives_the_frames_a_fresh_rendering_gives():
    """A camera holding still reuses its view of the ground; every frame is still the one rendered from nothing
    (the target moving across the kept ground, a changed gimbal seeing new ground)."""
    target = LinearTarget(start=(-6.0, 2.0), velocity=(3.0, 0.0), radius_m=1.5)
    clock = Clock(0.0)
    still = make_camera([target], clock=clock)
    for step, gimbal in enumerate([Gimbal(pan=0.0, tilt=-80.0)] * 4 + [Gimbal(pan=10.0, tilt=-70.0)] * 2):
        clock.now = step * 1.0
        still.set_state_enu((0.0, 0.0, 40.0), gimbal, yaw=3.0)
        fresh = make_camera([target], clock=clock)
        fresh.set_state_enu((0.0, 0.0, 40.0), gimbal, yaw=3.0)
        np.testing.assert_array_equal(still.render(clock.now), fresh.render(clock.now))
    first, later = still.render(0.0), still.render(3.0)
    assert not np.array_equal(first, later), "the target moved across the kept ground"
