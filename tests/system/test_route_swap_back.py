"""Issue 30 case 5 on the shipped ``uav1_sim.toml``: ``look_at``, then ``cromat gcs route uav1 pan_tilt datos 20``
(vision), then back to ``10``: the pan & tilt reads the RAL's current point again at once, so the DSP's record
shows the look_at target again after the swap back (before the fix nothing followed it and the gimbal stayed at
vision's last point while look_at showed running)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts import gri
from bbcs.session import local_client, open_session
from bbcs.testing import wait_until
from modules.vision.geodesy import LocalFrame
from modules.vision.module import VisionStatus

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_gcs_mission import ROBOT, SimRobot, connect, launch_robot  # noqa: E402

TARGET_EAST, TARGET_VE, GROUND_ALT = 30.0, 0.5, 12.0
"""Vision's simulated target and ground in bbcs_conf/uav1_sim.toml (target_east, target_ve, ground_alt)."""


def targets(robot: SimRobot, after: int) -> list[tuple[float, float]]:
    return [(c["fields"]["lat"], c["fields"]["lon"]) for c in robot.commands()[after:] if c["name"] == "SET_PT_TARGET"]


def near(point: tuple[float, float], lat: float, lon: float) -> bool:
    return abs(point[0] - lat) < 2e-5 and abs(point[1] - lon) < 2e-5


@pytest.mark.timeout(240)
def test_swapping_the_pan_tilt_input_back_brings_the_look_at_point_back(tmp_path: Path) -> None:
    la, record = launch_robot(tmp_path)
    bus = open_session(local_client(la.port))
    try:
        first_frame: list[float] = []
        decode = msgspec.msgpack.Decoder(VisionStatus).decode
        bus.declare_subscriber(keys.slot_key(ROBOT, "vision", "status"), lambda smp: first_frame or (
            (st := decode(smp.payload.to_bytes())).frame_stamp and first_frame.append(st.frame_stamp)))
        seen: list[float] = []
        bus.declare_subscriber(keys.slot_key(ROBOT, "vision", "target"), lambda smp: seen.append(time.monotonic()))
        robot = SimRobot(la, connect(la.port, "ground1"), record)
        try:
            home = robot.wait_state(lambda s: s.position is not None, 30, "a position").position
            wait_until(lambda: bool(first_frame), 30, "vision's first frame")
            up = robot.ensure_airborne()
            assert up.position is not None
            # vision's simulated target walks east from 30 m east of home (bbcs_conf/uav1_sim.toml); the look_at
            # point is one DSP grid cell (1e-4 degree, 11 m) north of where it will be: in the camera's view, so
            # vision sees the target, but on another cell than vision's points, so the record tells them apart
            world = LocalFrame(home.lat, home.lon, GROUND_ALT)
            east = TARGET_EAST + TARGET_VE * (time.monotonic() + 5.0 - first_frame[0])
            t_lat, t_lon, _ = (float(x) for x in world.to_lla([east, 0.0, 0.0]))
            lat, lon = round(t_lat, 4) + 1e-4, round(t_lon, 4)
            n = len(robot.commands())
            reply = robot.gcs.send(ROBOT, gri.LookAt(lat=lat, lon=lon, alt=GROUND_ALT))
            assert reply.accepted, reply.reason
            wait_until(lambda: any(near(p, lat, lon) for p in targets(robot, n)), 15, "the look_at point at the DSP")
            wait_until(lambda: bool(seen), 30, "vision seeing the target")

            n = len(robot.commands())
            assert robot.gcs.route(ROBOT, "pan_tilt", "datos", 20).routes["pan_tilt"]["datos"] == 20
            wait_until(lambda: any(not near(p, lat, lon) for p in targets(robot, n)), 15, "vision's points at the DSP")

            n = len(robot.commands())
            assert robot.gcs.route(ROBOT, "pan_tilt", "datos", 10).routes["pan_tilt"]["datos"] == 10
            wait_until(lambda: any(near(p, lat, lon) for p in targets(robot, n)), 10,
                       "the look_at point at the DSP again after the swap back")
            time.sleep(2.0)
            assert near(targets(robot, n)[-1], lat, lon), targets(robot, n)  # and it stays there
            assert any(t.id == reply.task_id for t in robot.state.tasks), "look_at no longer running"
        finally:
            robot.gcs.close()
    finally:
        bus.close()
        la.stop()
        la.cleanup()
