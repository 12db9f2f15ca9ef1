"""The vision process on a real router: telemetry in, a geolocated target and a path out."""

from __future__ import annotations

import math
import threading
import time

import msgspec
import numpy as np
import pytest

from bbcs import keys
from bbcs.contracts.geo import Attitude, GeoPoint
from bbcs.contracts.pan_tilt import DatosPT
from bbcs.contracts.path_follower import DatosSegCam
from bbcs.contracts.robot import RobotTelemetry
from bbcs.slots import OutputSlot, Publisher, Safety
from bbcs.testing import wait_until
from modules.vision.geodesy import LocalFrame
from modules.vision.module import VisionStatus, pose_and_gimbal

LAT0, LON0, ALT = 37.41, -6.0, 60.0
TARGET_EAST = 20.0


def hover_telemetry() -> RobotTelemetry:
    pan = 90.0  # east of a north-facing aircraft
    tilt = -math.degrees(math.atan2(ALT, TARGET_EAST))
    return RobotTelemetry(stamp=time.time(), position=GeoPoint(lat=LAT0, lon=LON0, alt=ALT),
                          attitude=Attitude(roll=0.0, pitch=0.0, yaw=0.0), heading_deg=0.0, pan_deg=pan,
                          tilt_deg=tilt)


def test_pose_needs_position_and_gimbal():
    assert pose_and_gimbal(RobotTelemetry(stamp=0.0)) is None
    pose, gimbal = pose_and_gimbal(hover_telemetry())
    assert (pose.lat, pose.alt, gimbal.pan) == (LAT0, ALT, 90.0)


@pytest.mark.parametrize("image", [(), ("width=320", "height=240", "hfov=50")], ids=["640x480", "320x240"])
def test_vision_process_geolocates_the_simulated_target(processes, router, sessions, image):
    """At the default image and at a smaller one with another field of view (the camera model follows the
    params: a wrong focal length would put the target metres off)."""
    s = sessions()
    size = [arg for param in image for arg in ("--param", param)]
    processes.start(["-m", "modules.vision", "--robot", "r1", "--connect", f"tcp/127.0.0.1:{router}",
                     "--param", "rate=20", "--param", f"target_east={TARGET_EAST}", "--param", "path_period=0.2",
                     *size])
    targets: list[DatosPT] = []
    paths: list[DatosSegCam] = []
    states: list[str] = []
    dt, dp, ds = (msgspec.msgpack.Decoder(t).decode for t in (DatosPT, DatosSegCam, VisionStatus))
    subs = [s.declare_subscriber(keys.slot_key("r1", "vision", "target"),
                                 lambda m: targets.append(dt(m.payload.to_bytes()))),
            s.declare_subscriber(keys.slot_key("r1", "vision", "path"),
                                 lambda m: paths.append(dp(m.payload.to_bytes()))),
            s.declare_subscriber(keys.slot_key("r1", "vision", "status"),
                                 lambda m: states.append(ds(m.payload.to_bytes()).state))]
    pub = Publisher(s, keys.slot_key("r1", "telemetry", "telemetry"),
                    OutputSlot("telemetry", RobotTelemetry, safety=Safety.UNSAFE))
    stop = threading.Event()

    def feed() -> None:
        while not stop.is_set():
            pub.publish(hover_telemetry())
            stop.wait(0.05)

    feeder = threading.Thread(target=feed, daemon=True)
    feeder.start()
    try:
        # the status comes on its own (unsafe) slot: no order with the targets, so it is waited for too
        wait_until(lambda: len(targets) >= 5 and paths and "found" in states, 60,
                   "targets, a path and the 'found' status from vision")
    finally:
        stop.set()
        feeder.join()
        pub.close()
        for sub in subs:
            sub.undeclare()
    truth = LocalFrame(LAT0, LON0, 0.0).to_lla(np.array([TARGET_EAST, 0.0, 0.0]))
    world = LocalFrame(LAT0, LON0, 0.0)
    for t in targets:
        east, north, _ = world.to_enu(t.latitud, t.longitud, t.altura)
        assert math.hypot(east - TARGET_EAST, north) < 1.0, (east, north)
    assert abs(targets[-1].ref_pan - 90.0) < 2.0
    last = paths[-1]
    assert last.n_points == len(last.puntos) >= 1
    end = last.puntos[-1]
    assert abs(end.latitud - truth[0]) < 1e-4 and abs(end.longitud - truth[1]) < 1e-4
    assert "found" in states
