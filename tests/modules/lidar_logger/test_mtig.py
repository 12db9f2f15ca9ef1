"""MTi-G driver against the simulator on a real pty: configuration bytes, poses, status timeline, faults."""

from __future__ import annotations

import os
import struct
import threading
import tty

import pytest

from bbcs.testing import wait_until
from modules.lidar_logger.mtdata import POSE_MODE, POSE_SETTINGS
from modules.lidar_logger.mtig import SCENARIO_AEROSPACE, MTiG, MTiGError, PoseSource
from modules.lidar_logger.vehicles import VEHICLES
from modules.lidar_logger.xbus import MID, build_frame


@pytest.fixture
def driver_factory():
    opened: list[MTiG] = []

    def make(port: str, **kw) -> MTiG:
        dev = MTiG(port, **kw)
        opened.append(dev)
        return dev

    try:
        yield make
    finally:
        for dev in opened:
            dev.close()


def test_configure_sends_the_seed_sequence_past_streamed_data(make_world, start_mtig, driver_factory) -> None:
    sim = start_mtig(make_world(10.0))
    dev = driver_factory(sim.port)  # opening the port drops what the device streamed before
    # the device streams its power-on output: a frame made after the port was opened is on the line before GoToConfig
    opened_at = sim.device.sample_counter
    wait_until(lambda: sim.device.sample_counter != opened_at, 10, "power-on MTData on the line")
    dev.configure(VEHICLES["PILATUS_PORTER"])
    mids = [mid for _, mid, _ in sim.device.received]
    assert mids == [
        MID.GOTO_CONFIG,
        MID.REQ_DID,
        MID.SET_OUTPUT_MODE,
        MID.SET_OUTPUT_SETTINGS,
        MID.SET_OUTPUT_SKIP_FACTOR,
        MID.SET_GPS_LEVER_ARM,
        MID.SET_SCENARIO,
        MID.REQ_DATA_LENGTH,
        MID.GOTO_MEASUREMENT,
    ]
    data = {mid: d for _, mid, d in sim.device.received}
    assert data[MID.SET_OUTPUT_MODE] == bytes.fromhex("0834")
    assert data[MID.SET_OUTPUT_SETTINGS] == bytes.fromhex("00000206")
    assert data[MID.SET_OUTPUT_SKIP_FACTOR] == bytes.fromhex("FFFF")
    assert data[MID.SET_SCENARIO] == struct.pack(">H", SCENARIO_AEROSPACE)
    assert struct.unpack(">3f", data[MID.SET_GPS_LEVER_ARM]) == pytest.approx((-0.45, -0.04, 0.0))
    assert sim.device.lever_arm == pytest.approx((-0.45, -0.04, 0.0))
    assert sim.device.state == "measurement" and sim.device.stream_interval() is None
    assert dev.unexpected_frames > 0, "streamed MTData before GoToConfig must have been skipped"
    assert dev.device_id == sim.device.device_id
    assert (dev.mode, dev.settings) == (POSE_MODE, POSE_SETTINGS)


def test_read_pose_returns_what_the_device_sent(make_world, start_mtig, driver_factory) -> None:
    sim = start_mtig(make_world(10.0, gps_fix_at=0.0, xkf_valid_at=0.0))
    dev = driver_factory(sim.port)
    dev.configure(VEHICLES["CB5000"])
    for _ in range(5):
        got = dev.read_pose()
        _, sent = sim.device.poses_sent[-1]
        assert got.utc == sent.utc and got.status == sent.status == 7 and got.valid == 1
        for a, b in zip((*got.euler, *got.lla, *got.vel), (*sent.euler, *sent.lla, *sent.vel), strict=True):
            assert abs(a - b) <= 2**-32


def test_status_goes_0_5_7_and_only_7_is_valid(make_world, start_mtig, driver_factory) -> None:
    world = make_world(10.0, gps_fix_at=1.0, xkf_valid_at=2.0)
    sim = start_mtig(world)
    dev = driver_factory(sim.port)
    dev.configure(VEHICLES["CB5000"])
    seen: list[tuple[int, int]] = []
    source = PoseSource(
        dev, period=0.02, clock=world.clock, on_pose=lambda p: seen.append((p.status, p.valid))
    )
    source.start()
    try:
        first = source.wait_valid(threading.Event())
    finally:
        source.stop()
    assert first is not None and first.pose.status == 7 and first.pose.valid == 1
    statuses = [s for s, _ in seen]
    assert statuses[0] == 0 and 5 in statuses and statuses == sorted(statuses)
    assert all(v == (1 if s == 7 else 0) for s, v in seen)
    assert sim.device.first_status_time(5) < sim.device.first_status_time(7)


def test_an_error_message_from_the_device_raises(make_world, start_mtig, driver_factory) -> None:
    sim = start_mtig(make_world(10.0))
    dev = driver_factory(sim.port)
    with pytest.raises(MTiGError, match=r"error 0x04 \(invalid message\)"):
        dev.request(MID.SET_OUTPUT_MODE, bytes.fromhex("0834"))  # still in measurement state


def test_a_device_that_ignored_the_settings_is_caught_by_the_length_check(
    make_world, start_mtig, driver_factory
) -> None:
    sim = start_mtig(make_world(10.0))
    dev = driver_factory(sim.port)
    dev.goto_config()
    dev.set_output(POSE_MODE, POSE_SETTINGS)
    sim.device.settings = 0x0004  # the unit kept float Euler without UTC
    with pytest.raises(MTiGError, match="reports MTData of 37 bytes.*should give 67"):
        dev.check_data_length()


def test_line_noise_is_skipped(make_world, start_mtig, driver_factory) -> None:
    sim = start_mtig(make_world(10.0, gps_fix_at=0.0, xkf_valid_at=0.0))
    dev = driver_factory(sim.port)
    dev.configure(VEHICLES["CB5000"])
    corrupt = bytearray(build_frame(MID.MTDATA, bytes(67)))
    corrupt[10] ^= 0xFF
    sim.inject(b"\x00\x01\x02" + bytes(corrupt))
    assert dev.read_pose().valid == 1
    assert dev.parser.bad_checksum >= 1 and dev.parser.discarded_bytes >= 3


def test_a_silent_port_times_out_after_the_retries(driver_factory) -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        dev = driver_factory(os.ttyname(slave), reply_timeout=0.1, retries=2)
        with pytest.raises(MTiGError, match="did not answer message 0x30"):
            dev.request(MID.GOTO_CONFIG)
        assert dev.timeouts == 2
        assert os.read(master, 100) == build_frame(MID.GOTO_CONFIG) * 2
    finally:
        os.close(master)
        os.close(slave)


def test_pose_source_reports_a_device_that_stops_answering(make_world, start_mtig, driver_factory) -> None:
    world = make_world(10.0, gps_fix_at=0.0, xkf_valid_at=0.0)
    sim = start_mtig(world)
    dev = driver_factory(sim.port)  # the pose source polls with its own reply timeout: configure at the default
    dev.configure(VEHICLES["CB5000"])
    source = PoseSource(dev, period=0.02, clock=world.clock, max_failures=3)
    source.start()
    try:
        assert source.wait_valid(threading.Event()) is not None
        sim.stop()
        wait_until(lambda: source.failed is not None, 20, "the pose source giving up")
    finally:
        source.stop()
    assert source.failed is not None and "stopped answering" in source.failed
    assert source.wait_valid(threading.Event()) is None


def test_pose_source_reports_corrupt_frames_coalesced(make_world, start_mtig, driver_factory) -> None:
    """MTData with bad checksums on the line (written by hand, not by build_frame) are dropped and reported to
    on_refused: the first at once, a burst in one later report with its count; the poses go on."""
    world = make_world(10.0, gps_fix_at=0.0, xkf_valid_at=0.0)
    sim = start_mtig(world)
    dev = driver_factory(sim.port)
    dev.configure(VEHICLES["CB5000"])
    reports: list[str] = []
    source = PoseSource(dev, period=0.02, clock=world.clock, on_refused=reports.append)
    source.start()
    try:
        assert source.wait_valid(threading.Event()) is not None
        corrupt = bytes((0xFA, 0xFF, 0x32, 3, 1, 2, 3, 0x00))  # checksum 0x00, should be 0xC6
        sim.inject(corrupt)
        wait_until(lambda: reports, 10, "the first report")
        sim.inject(corrupt * 30)
        wait_until(lambda: source.refusals.total >= 31, 10, "the burst counted")
        wait_until(lambda: len(reports) >= 2, 10, "the burst's report")
        samples = source.samples
        wait_until(lambda: source.samples > samples + 5, 10, "poses after the burst")
    finally:
        source.stop()
    assert "MTi-G: frame dropped (bad checksum" in reports[0]
    assert len(reports) <= 3 and "refused in the last" in reports[1]
    assert source.refusals.total == dev.parser.damaged >= 31
