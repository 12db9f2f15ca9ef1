"""The simulated world and devices: ray casting, reported poses, scan geometry, running as a process."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import numpy as np
import pytest

from modules.lidar_logger.geodesy import ecef_from_nwu, euler_to_matrix
from modules.lidar_logger.ldmrs_proto import Cmd, Param, command_payload
from modules.lidar_logger.mtdata import utc_to_posix
from modules.lidar_logger.sim import Flight, LdmrsDevice, LdmrsOptions, Terrain, World


def test_ray_cast_hits_the_terrain() -> None:
    terrain = Terrain()
    rng = np.random.default_rng(0)
    n = 400
    origins = np.column_stack((rng.uniform(-500, 500, n), rng.uniform(-500, 500, n), np.full(n, 80.0)))
    dirs = np.column_stack((rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), rng.uniform(-1, -0.05, n)))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    dist = terrain.ray_cast(origins, dirs, 300.0)
    hit = np.isfinite(dist)
    assert hit.sum() > 300
    p = origins[hit] + dirs[hit] * dist[hit, None]
    assert np.abs(p[:, 2] - terrain.height(p[:, 0], p[:, 1])).max() < 1e-8
    # nothing closer: the terrain stays below every ray before its hit
    for k in np.nonzero(hit)[0][:40]:
        s = np.linspace(0, dist[k], 400)[:-1]
        q = origins[k] + dirs[k] * s[:, None]
        assert (q[:, 2] > terrain.height(q[:, 0], q[:, 1])).all()
    up = terrain.ray_cast(np.array([[0, 0, 80.0]]), np.array([[0, 0, 1.0]]), 300.0)
    assert np.isnan(up[0])


def test_max_slope_bounds_the_gradient() -> None:
    terrain = Terrain()
    e, n = np.meshgrid(np.linspace(-1000, 1000, 401), np.linspace(-1000, 1000, 401))
    ge, gn = terrain.gradient(e, n)
    assert np.hypot(ge, gn).max() <= terrain.max_slope
    h = 1e-4
    assert (terrain.height(e + h, n) - terrain.height(e - h, n)) / (2 * h) == pytest.approx(ge, abs=1e-6)


def test_reported_pose_describes_the_true_aircraft() -> None:
    world = World(
        flight=Flight(waypoints=((0.0, 0.0), (1000.0, 0.0)), speed=25.0, roll=2.0, pitch=-1.5, crab=3.0)
    )
    t = 30.0
    pose = world.true_pose(t)
    assert pose.valid == 1 and pose.status == 7
    assert utc_to_posix(pose.utc) == pytest.approx(world.utc(t), abs=1e-6)
    pos, vel, rot = world.flight.state(np.array([t]))
    assert world.lla_to_terrain(np.array(pose.lla)) == pytest.approx(pos[0], abs=1e-6)
    # Euler and velocity are in the local NWU frame at the aircraft, not the terrain frame
    ecef_nwu = ecef_from_nwu(pose.lla[0], pose.lla[1])
    terrain_from_ecef = world._ecef_from_terrain.T
    assert terrain_from_ecef @ ecef_nwu @ euler_to_matrix(np.array(pose.euler)) == pytest.approx(
        rot[0], abs=1e-12
    )
    assert terrain_from_ecef @ ecef_nwu @ np.array(pose.vel) == pytest.approx(vel[0], abs=1e-9)
    assert pose.euler[0] == pytest.approx(2.0, abs=0.01) and pose.euler[2] == pytest.approx(
        -90.0 - 3.0, abs=0.02
    )


def test_status_timeline_with_a_dropout() -> None:
    world = World(gps_fix_at=1.0, xkf_valid_at=2.0, dropouts=((5.0, 6.0),))
    assert [world.status(t) for t in (0.5, 1.5, 3.0, 5.5, 6.5)] == [0, 5, 7, 5, 7]
    assert world.true_pose(0.5).lla == (0.0, 0.0, 0.0) and world.true_pose(0.5).utc.month == 0


def test_scans_follow_the_configured_geometry() -> None:
    dev = LdmrsDevice(World(), LdmrsOptions(clutter_fraction=0.05, dirt_fraction=0.02, seed=4))
    for param, value in (
        (Param.START_ANGLE, 1600),
        (Param.END_ANGLE, (-1600) & 0xFFFF),
        (Param.DATA_OUTPUT_FLAGS, 0xFFEE),
    ):
        dev.handle_command(command_payload(Cmd.SET_PARAMETER, param, value), 0.0)
    dev.handle_command(command_payload(Cmd.START_MEASURE), 10.0)
    assert not dev.due(10.0) and dev.due(10.0 + 0.04 + dev.sweep)
    scan = dev.take_scan(send=True)
    assert scan is not None and dev.sweep == pytest.approx(0.08 * 100 / 360)
    a = scan.angle_ticks
    assert a.max() <= 1600 and a.min() >= -1600 and np.all(np.diff(a) <= 0)
    assert np.all(a % 8 == 0), "constant 0.25 deg steps"
    assert set(scan.layer[a > 35 * 32].tolist()) <= {0, 1}, "only the lower two layers beyond +35 deg"
    assert set(scan.layer[a <= 35 * 32].tolist()) == {0, 1, 2, 3}
    assert scan.n_points > 1400
    second = scan.echo == 1
    assert second.any() and set(scan.wire_flags[~second & (scan.wire_flags != 0)].tolist()) <= {3, 8}
    assert (scan.end_ntp - scan.start_ntp) / 2**32 == pytest.approx(dev.sweep, abs=1e-6)


def test_simulator_process_prints_its_ports_and_stops_on_sigterm() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "modules.lidar_logger.sim", "--time-scale", "5"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        info = json.loads(proc.stdout.readline())
        assert (
            info["mtig_port"].startswith("/dev/") and info["ldmrs_host"] == "127.0.0.1" and info["ldmrs_port"]
        )
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=10)
        assert proc.returncode == 0 and "scans_sent" in json.loads(out.strip().splitlines()[-1])
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
