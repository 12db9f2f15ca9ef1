"""Render -> detect -> geolocate round trips and the pipeline's publish/lost behaviour.

Stated bound: with the aircraft 60-150 m above flat ground, |roll|, |pitch| <= 10 deg, a 1.5 m radius target
within 250 m slant range and large enough to be detected, the geolocated target is within 0.5 m
(horizontal) of the simulator's truth, for both gimbal mounts.
"""

import numpy as np
import pytest

from modules.vision.geodesy import LocalFrame
from modules.vision.geometry import CameraModel, pointing_angles
from modules.vision.pipeline import VisionConfig, VisionPipeline
from modules.vision.pose import AircraftPose, Gimbal
from modules.vision.scene import LinearTarget
from modules.vision.sim_camera import SimulatedCamera
from modules.vision.source import Frame
from modules.vision.tracker import TrackerConfig, TrackState

WORLD = LocalFrame(37.41, -6.0, 0.0)
GEO_BOUND_M = 0.5


class Clock:
    def __init__(self, now=0.0):
        self.now = now

    def __call__(self):
        return self.now


def enu_of(cam):
    return WORLD.to_enu(cam.pose.lat, cam.pose.lon, cam.pose.alt)


def aim_at(cam, point):
    aim = pointing_angles(cam.pose, enu_of(cam), point, stabilised=cam.camera.stabilised)
    cam.set_state(cam.pose, aim)
    return aim


@pytest.mark.parametrize("stabilised", [True, False])
def test_round_trip_over_random_poses(stabilised):
    rng = np.random.default_rng(11)
    camera = CameraModel(stabilised=stabilised)
    checked = 0
    for k in range(40):
        target = LinearTarget(start=(rng.uniform(-50, 50), rng.uniform(-50, 50)), radius_m=1.5)
        cam = SimulatedCamera(WORLD, camera=camera, targets=[target], clock=Clock(), epoch=0.0, seed=k, noise_sigma=6.0)
        cam.set_state_enu(
            (rng.uniform(-150, 150), rng.uniform(-150, 150), rng.uniform(60, 150)),
            Gimbal(pan=0, tilt=-90),
            roll=rng.uniform(-10, 10),
            pitch=rng.uniform(-10, 10),
            yaw=rng.uniform(-180, 180),
        )
        truth = cam.targets_enu(0.0)[0]
        if np.linalg.norm(truth - enu_of(cam)) > 250.0:
            continue
        aim = aim_at(cam, truth + [rng.uniform(-5, 5), rng.uniform(-5, 5), 0.0])
        # Far, oblique targets are small (confidence ~0.4): accept them, this test is about geometry.
        tracker = TrackerConfig(confidence_on=0.2, confidence_off=0.1, confirm_hits=1, confirm_s=0.0)
        pipe = VisionPipeline(VisionConfig(camera=camera, tracker=tracker))
        result = pipe.process(cam.read(), cam.pose, aim)
        assert result.publish and result.state is TrackState.FOUND
        got = WORLD.to_enu(result.target.lat, result.target.lon, result.target.alt)
        assert np.hypot(*(got - truth)[:2]) < GEO_BOUND_M
        assert got[2] == pytest.approx(0.0, abs=1e-9)
        assert result.target.range_m == pytest.approx(np.linalg.norm(truth - enu_of(cam)), abs=GEO_BOUND_M)
        # The pointing angles in the fix point the camera back at the target.
        again = pointing_angles(cam.pose, enu_of(cam), truth, stabilised=stabilised)
        assert result.target.pointing.pan == pytest.approx(again.pan, abs=0.5)
        assert result.target.pointing.tilt == pytest.approx(again.tilt, abs=0.5)
        checked += 1
    assert checked >= 25


def test_nadir_hover_target_below_gives_aircraft_lat_lon():
    cam = SimulatedCamera(WORLD, targets=[LinearTarget(start=(0.0, 0.0))], clock=Clock(), epoch=0.0)
    cam.set_state_enu((0.0, 0.0, 80.0), Gimbal(pan=0.0, tilt=-90.0))
    result = VisionPipeline(VisionConfig(tracker=TrackerConfig(confirm_hits=1, confirm_s=0.0))).process(
        cam.read(), cam.pose, cam.gimbal
    )
    assert result.target.lat == pytest.approx(WORLD.lat0, abs=1e-6)
    assert result.target.lon == pytest.approx(WORLD.lon0, abs=1e-6)
    assert result.target.pointing.tilt == pytest.approx(-90.0, abs=0.5)


def test_track_acquire_publish_lose():
    clock = Clock(0.0)
    target = LinearTarget(start=(0.0, 30.0), velocity=(1.0, 0.0), radius_m=1.5)
    cam = SimulatedCamera(WORLD, targets=[target], clock=clock, epoch=0.0, noise_sigma=5.0)
    cam.set_state_enu((0.0, 0.0, 80.0), Gimbal(pan=0.0, tilt=-90.0))
    pipe = VisionPipeline(VisionConfig(tracker=TrackerConfig(confirm_hits=3, confirm_s=0.1, lose_s=0.5)))
    results = []
    for k in range(5):  # follow the target: 10 Hz
        clock.now = 0.1 * k
        aim = aim_at(cam, cam.targets_enu(clock.now)[0])
        results.append(pipe.process(cam.read(), cam.pose, aim))
    assert [r.state for r in results] == [TrackState.TENTATIVE] * 2 + [TrackState.FOUND] * 3
    assert [r.publish for r in results] == [False, False, True, True, True]
    assert all(r.trajectory is None for r in results[:2])
    wps = results[-1].trajectory
    assert wps.shape == (3, 3)
    assert (wps[-1, 0], wps[-1, 1]) == pytest.approx((results[-1].target.lat, results[-1].target.lon))

    cam.set_state(cam.pose, Gimbal(pan=180.0, tilt=-10.0))  # look away: nothing detected
    states = []
    for k in range(5, 12):
        clock.now = 0.1 * k
        r = pipe.process(cam.read(), cam.pose, cam.gimbal)
        assert not r.publish and r.detection is None
        states.append(r.state)
    # last hit at t=0.4; lose_s=0.5 -> still FOUND (coasting) up to 0.8, LOST from 0.9
    assert states == [TrackState.FOUND] * 4 + [TrackState.LOST] * 3
    assert pipe.frames == 12 and pipe.published == 3


def test_detection_that_cannot_be_geolocated_is_a_miss():
    cam = SimulatedCamera(WORLD, targets=[LinearTarget(start=(0.0, 0.0))], clock=Clock(), epoch=0.0)
    cam.set_state_enu((0.0, 0.0, 80.0), Gimbal(pan=0.0, tilt=-90.0))
    frame = cam.read()
    # Claim the ground is above the aircraft: the ray cannot reach it.
    pipe = VisionPipeline(VisionConfig(ground_alt=200.0, tracker=TrackerConfig(confirm_hits=1, confirm_s=0.0)))
    result = pipe.process(frame, cam.pose, cam.gimbal)
    assert result.detection is not None and result.target is None
    assert result.state is TrackState.LOST and not result.publish
    assert pipe.geolocation_failures == 1


def test_frame_size_must_match_the_camera_model():
    pipe = VisionPipeline(VisionConfig(camera=CameraModel(width=320, height=240)))
    frame = Frame(image=np.zeros((480, 640, 3), np.uint8), timestamp=0.0, seq=4)
    with pytest.raises(ValueError, match="frame 4 is 640x480"):
        pipe.process(frame, AircraftPose(lat=0.0, lon=0.0, alt=50.0), Gimbal(pan=0.0, tilt=-90.0))


def test_bad_config_and_frame():
    with pytest.raises(ValueError):
        VisionConfig(max_range_m=0.0)
    with pytest.raises(ValueError):
        VisionConfig(ground_alt=float("inf"))
    with pytest.raises(ValueError, match="uint8"):
        Frame(image=np.zeros((4, 4), np.float32), timestamp=0.0, seq=0)
    with pytest.raises(ValueError, match="shape"):
        Frame(image=np.zeros((4, 4, 4), np.uint8), timestamp=0.0, seq=0)
