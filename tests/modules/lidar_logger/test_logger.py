"""Whole runs through the real transports (pty + TCP) against the simulators, on an accelerated clock.

The 60-second flight (12x faster than real time) is run once and checked from several sides: what the logs
hold against what the simulators sent, the binary log against the text log, the order of start-up, and the
georeferenced cloud against the terrain it was scanned from.

Georeferencing tolerance (vertical distance to the terrain), derived from what rounds or quantises:
  - LD-MRS range resolution 1 cm: a point moves up to 0.005 m along its beam;
  - text log only: the pose UTC is printed in whole milliseconds (truncated), so time alignment moves the
    IMU up to |v| x 0.001 s too far (0.02 m at 20 m/s); the binary log keeps nanoseconds;
  - everything else stays below 1 mm: 8 decimals of LLA (0.56 mm of latitude), Euler (1.7e-8 m at 200 m),
    x,y,z (5e-9 m), scan times (1 us x |v|), fixed 16.32 MTi-G values (2.3e-10), the curvature of the local
    vertical between pose and point (< 0.1 mm);
so a 3-D error e <= 0.005 + 0.001 + (|v| x 0.001 for text) m, and its vertical distance to a surface of
slope s is at most e x (1 + s_max) (a horizontal error e moves the surface by s_max x e).
"""

from __future__ import annotations

import io
import threading
from collections import defaultdict

import numpy as np
import pytest

from bbcs.testing import wait_until
from modules.lidar_logger.binlog import iter_records, read_binary_log
from modules.lidar_logger.clock import ScaledClock
from modules.lidar_logger.config import read_config_file
from modules.lidar_logger.flags import wire_to_seed
from modules.lidar_logger.georef import georeference
from modules.lidar_logger.ldmrs_proto import Cmd
from modules.lidar_logger.logger import LidarLogger, LoggerSettings
from modules.lidar_logger.mtdata import utc_to_posix
from modules.lidar_logger.sim import Flight, LdmrsOptions, LdmrsSimulator, MTiGSimulator, World
from modules.lidar_logger.textlog import format_scan, read_text_log

SCALE = 4.0  # sim seconds per real second: the logger keeps up at this rate also beside other test workers


def settings_for(imu: MTiGSimulator, lidar: LdmrsSimulator, out, **kw) -> LoggerSettings:
    base = dict(
        mtig_port=imu.port,
        ldmrs_host="127.0.0.1",
        ldmrs_port=lidar.port,
        out_dir=out,
        binary=True,
        mounting=imu.world.mounting,
    )
    base.update(kw)
    return LoggerSettings(**base)


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    world = World(
        clock=ScaledClock(SCALE),
        gps_fix_at=1.0,
        xkf_valid_at=3.0,
        dropouts=((30.0, 33.0),),
        flight=Flight(waypoints=((-650.0, -300.0), (650.0, 300.0)), speed=20.0, height=90.0),
    )
    imu = MTiGSimulator(world).start()
    lidar = LdmrsSimulator(world, LdmrsOptions(return_fraction=0.12, seed=7)).start()
    try:
        out = io.StringIO()
        logger = LidarLogger(
            settings_for(imu, lidar, tmp_path_factory.mktemp("flight"), duration_s=60.0, pose_stale_s=2.0),
            clock=world.clock,
            out=out,
        )
        summary = logger.run()
    finally:
        lidar.stop()
        imu.stop()
    return world, imu, lidar, summary, out.getvalue()


def test_the_flight_stops_on_duration_with_closed_complete_files(flight) -> None:
    _, _, lidar, summary, progress = flight
    assert summary.reason == "duration" and summary.exit_code == 0 and summary.error is None
    assert summary.stop_acknowledged
    assert lidar.device.commands[-1][1] == Cmd.STOP_MEASURE and not lidar.device.measuring
    cfg = read_config_file(summary.config_path)
    assert cfg["end_reason"] == "duration" and int(cfg["scans_written"]) == summary.scans_written
    assert summary.folder.name.startswith("Scan_Y2010_M09_D10_H07M30S0")
    assert summary.text_path.name == "LogFile_" + summary.folder.name[len("Scan_") :]
    assert summary.text_path.stat().st_size == summary.text_bytes
    assert sum(p.stat().st_size for p in summary.binary_paths) == summary.binary_bytes
    assert "scans/s" in progress and "pose valid (status 7)" in progress
    # 60 s at 12.5 Hz: every scan ending within 60 s of StartMeasure (the simulator never skips one)
    assert summary.scans_received >= 749
    log = read_text_log(summary.text_path)
    assert log.end_time[-1] - log.start_time[0] >= 59.9


def test_the_text_log_holds_exactly_what_the_scanner_sent(flight) -> None:
    _, _, lidar, summary, _ = flight
    sent = lidar.device.sent_scans
    log = read_text_log(summary.text_path)
    assert summary.scans_received == len(sent), "every scan sent before StopMeasure was received"
    assert (
        log.n_scans == summary.scans_written == len(sent) - summary.scans_dropped - summary.scans_after_stop
    )
    assert log.total_points == summary.points_written
    assert set(log.scan_index.tolist()) <= set(range(1, len(sent) + 1))
    for k in range(log.n_scans):
        src = sent[log.scan_index[k] - 1]
        a, b = log.first_point[k], log.first_point[k] + log.n_points[k]
        assert log.n_points[k] == src.n_points
        assert abs(log.start_time[k] - src.start_time) < 1e-6 and log.scan_flags[k] == src.scan_flags
        assert np.abs(log.xyz[a:b] - src.cartesian()).max(initial=0) <= 5e-9
        assert np.array_equal(log.flags[a:b], wire_to_seed(src.wire_flags))
        assert np.array_equal(log.layer[a:b], src.layer) and np.array_equal(log.echo[a:b], src.echo)
        assert np.array_equal(log.offset_us[a:b], src.time_offsets_us())
        assert np.array_equal(log.echo_width[a:b], src.echo_width_cm / 100.0)
    assert log.total_points == sum(sent[i - 1].n_points for i in log.scan_index)


def test_every_logged_pose_is_one_the_mti_g_sent(flight) -> None:
    _, imu, _, summary, _ = flight
    by_ms = defaultdict(list)  # the text log keeps the UTC in whole milliseconds
    for _, pose in imu.device.poses_sent:
        if pose.utc.month:
            whole_s = round(utc_to_posix(pose.utc) - pose.utc.nano * 1e-9)
            by_ms[whole_s * 1000 + pose.utc.nano // 1_000_000].append(pose)
    log = read_text_log(summary.text_path)
    forced_invalid = 0
    for k in range(log.n_scans):
        candidates = by_ms[round(log.pose_time[k] * 1000)]
        match = [
            p
            for p in candidates
            if np.abs(np.r_[p.euler, p.lla, p.vel] - np.r_[log.euler[k], log.lla[k], log.vel[k]]).max()
            <= 6e-9
        ]
        assert match, f"scan {log.scan_index[k]}: pose not among those sent"
        assert log.status[k] == match[0].status
        if log.valid[k] != match[0].valid:
            assert log.valid[k] == 0
            forced_invalid += 1
    assert forced_invalid == summary.stale_pose_scans
    assert np.all(np.diff(log.pose_time) >= 0), "the newest pose is attached, so pose times never go back"
    dropout = log.status == 5
    assert dropout.any() and (log.valid[dropout] == 0).all(), "GPS/XKF dropout logged as Valid 0"


def test_the_binary_log_matches_the_text_log(flight) -> None:
    _, _, _, summary, _ = flight
    regenerated = "".join(format_scan(r) for r in iter_records(summary.binary_paths[0]))
    assert regenerated == summary.text_path.read_text()
    b, t = read_binary_log(summary.binary_paths[0]), read_text_log(summary.text_path)
    assert np.array_equal(b.scan_index, t.scan_index) and np.array_equal(b.flags, t.flags)
    assert np.abs(b.xyz - t.xyz).max() <= 5e-9
    assert summary.binary_bytes * 5 < summary.text_bytes


def test_nothing_starts_before_the_pose_is_valid(flight) -> None:
    _, imu, lidar, summary, _ = flight
    t_valid = imu.device.first_status_time(7)
    statuses_before = {p.status for t, p in imu.device.poses_sent if t < t_valid}
    assert {0, 5} <= statuses_before, "the logger polled through status 0 and 5 first"
    assert lidar.connected_at and lidar.connected_at[0] >= t_valid
    assert lidar.device.commands[0][0] >= t_valid
    assert lidar.device.measure_started_at > t_valid
    assert read_text_log(summary.text_path).valid[0] == 1


@pytest.mark.parametrize("source", ["text", "binary"])
def test_georeferenced_points_lie_on_the_terrain(flight, source) -> None:
    world, _, _, summary, _ = flight
    log = read_text_log(summary.text_path) if source == "text" else read_binary_log(summary.binary_paths[0])
    result = georeference(log, world.mounting, time_align=True)
    pts = world.enu_to_terrain(result.enu, result.origin_lla)
    residual = pts[:, 2] - world.terrain.height(pts[:, 0], pts[:, 1])
    s_max, speed = world.terrain.max_slope, world.flight.speed
    tolerance = (0.005 + 0.001 + (speed * 0.001 if source == "text" else 0.0)) * (1 + s_max)
    assert np.abs(residual).max() <= tolerance
    expected = (log.point_valid == 1) & (log.valid[log.point_scan] == 1)
    assert len(result.enu) == expected.sum() > 60_000
    assert np.ptp(pts[:, 0]) > 900, "the cloud covers the flight line"
    # the flagged echoes (clutter, dirt) really are off the ground: leaving them out matters
    flagged = np.nonzero((log.point_valid == 0) & (log.valid[log.point_scan] == 1))[0]
    log.point_valid[flagged] = 1
    everything = georeference(log, world.mounting, time_align=True)
    pts_all = world.enu_to_terrain(everything.enu, everything.origin_lla)
    assert np.abs(pts_all[:, 2] - world.terrain.height(pts_all[:, 0], pts_all[:, 1])).max() > 10


def test_a_silent_scanner_stops_the_run_after_the_event_timeout(
    make_world, start_mtig, start_ldmrs, tmp_path
) -> None:
    world = make_world(10.0, gps_fix_at=0.2, xkf_valid_at=0.5)
    imu = start_mtig(world)
    lidar = start_ldmrs(world, LdmrsOptions(return_fraction=0.1, silent_after=3.0))
    summary = LidarLogger(settings_for(imu, lidar, tmp_path), clock=world.clock, out=io.StringIO()).run()
    assert summary.reason == "timeout" and summary.exit_code == 3
    assert summary.stop_acknowledged and not lidar.device.measuring
    sent = lidar.device.sent_scans
    # scans ending in the first 3 s of measuring: starts at 0.04 + 0.08 k, each 22.2 ms long -> k = 0..36
    assert len(sent) == 37 and summary.scans_written + summary.scans_dropped == len(sent)
    assert read_text_log(summary.text_path).n_scans == summary.scans_written
    assert read_binary_log(summary.binary_paths[0]).n_scans == summary.scans_written
    assert read_config_file(summary.config_path)["end_reason"] == "timeout"


def test_a_stop_request_ends_the_run_cleanly(make_world, start_mtig, start_ldmrs, tmp_path) -> None:
    world = make_world(10.0, gps_fix_at=0.2, xkf_valid_at=0.5)
    imu = start_mtig(world)
    lidar = start_ldmrs(world, LdmrsOptions(return_fraction=0.1))
    logger = LidarLogger(settings_for(imu, lidar, tmp_path), clock=world.clock, out=io.StringIO())

    def stop_after_ten_scans() -> None:
        wait_until(lambda: len(lidar.device.sent_scans) >= 10, 60, "ten scans")
        logger.request_stop()

    stopper = threading.Thread(target=stop_after_ten_scans, daemon=True)
    stopper.start()
    summary = logger.run()
    stopper.join(5)
    assert summary.reason == "signal" and summary.exit_code == 0 and summary.stop_acknowledged
    assert summary.scans_written >= 1
    assert summary.scans_written + summary.scans_dropped == len(lidar.device.sent_scans) >= 10
    assert read_text_log(summary.text_path).n_scans == summary.scans_written


def test_stop_while_waiting_for_a_valid_pose_creates_nothing(
    make_world, start_mtig, start_ldmrs, tmp_path
) -> None:
    world = make_world(1.0, gps_fix_at=100.0, xkf_valid_at=200.0)
    imu = start_mtig(world)
    lidar = start_ldmrs(world)
    polled = threading.Event()
    logger = LidarLogger(settings_for(imu, lidar, tmp_path), clock=world.clock, out=io.StringIO(),
                         on_pose=lambda _: polled.set())

    def stop_after_a_pose() -> None:  # not after a fixed time: a loaded machine may not have polled one by then
        polled.wait(60)
        logger.request_stop()

    stopper = threading.Thread(target=stop_after_a_pose, daemon=True)
    stopper.start()
    try:
        summary = logger.run()
    finally:
        polled.set()
        stopper.join(10)
    assert summary.reason == "signal" and summary.folder is None
    assert not lidar.connected_at and list(tmp_path.iterdir()) == []
    assert summary.poses > 0 and summary.valid_poses == 0


def test_an_unreachable_scanner_is_an_error_and_leaves_no_folder(make_world, start_mtig, tmp_path) -> None:
    world = make_world(10.0, gps_fix_at=0.0, xkf_valid_at=0.0)
    imu = start_mtig(world)
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    settings = LoggerSettings(mtig_port=imu.port, ldmrs_host="127.0.0.1", ldmrs_port=port, out_dir=tmp_path)
    summary = LidarLogger(settings, clock=world.clock, out=io.StringIO()).run()
    assert summary.reason == "error" and summary.exit_code == 1 and "cannot connect" in summary.error
    assert list(tmp_path.iterdir()) == []


def test_a_missing_mti_g_port_is_an_error(tmp_path) -> None:
    settings = LoggerSettings(mtig_port=str(tmp_path / "ttyUSB9"), ldmrs_host="127.0.0.1", out_dir=tmp_path)
    summary = LidarLogger(settings, out=io.StringIO()).run()
    assert summary.reason == "error" and summary.exit_code == 1 and "ttyUSB9" in summary.error


def test_a_failing_disk_ends_the_run_with_the_scanner_idle_and_files_closed(
    make_world, start_mtig, start_ldmrs, tmp_path, monkeypatch
) -> None:
    from modules.lidar_logger import textlog

    real_write = textlog.TextLogWriter.write
    calls = []

    def write(self, record):  # the SD card fills up after 10 scans
        calls.append(record.index)
        if len(calls) > 10:
            raise OSError(28, "No space left on device")
        real_write(self, record)

    monkeypatch.setattr(textlog.TextLogWriter, "write", write)
    world = make_world(10.0, gps_fix_at=0.2, xkf_valid_at=0.5)
    imu = start_mtig(world)
    lidar = start_ldmrs(world, LdmrsOptions(return_fraction=0.1))
    summary = LidarLogger(settings_for(imu, lidar, tmp_path), clock=world.clock, out=io.StringIO()).run()
    assert summary.reason == "error" and "No space left" in summary.error and summary.exit_code == 1
    assert summary.stop_acknowledged and not lidar.device.measuring
    assert read_text_log(summary.text_path).n_scans == 10
    assert read_binary_log(summary.binary_paths[0]).n_scans >= 10
    assert read_config_file(summary.config_path)["end_reason"] == "error"
