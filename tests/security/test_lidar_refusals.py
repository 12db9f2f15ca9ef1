"""Issue 12, "the same for the MTi-G and LD-MRS drivers", by effect: the LD-MRS simulator sends, over real TCP,
scans the scanner cannot produce (ticks per rotation 11 000), and the MTi-G simulator answers some ReqData, on
its pty, with a well-formed MTData whose latitude is 200°. The real lidar logger module drops each one, reports
it on its ERROR slot (SCAN_REFUSED / POSE_REFUSED from bbcs.contracts.error_codes) and never logs or publishes
it: no refused scan number is in the binary log, no pose with that latitude on the ``pose`` slot; good data
keeps flowing."""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Iterator
from pathlib import Path

import msgspec
import numpy as np
import pytest

from bbcs import keys
from bbcs.contracts.error_codes import LidarLoggerError
from bbcs.contracts.errors import ErrorReport
from bbcs.testing import stop_process, wait_until
from modules.lidar_logger.binlog import SCANS_SUFFIX, read_binary_records
from modules.lidar_logger.clock import ScaledClock
from modules.lidar_logger.ldmrs_scan import TICKS_PER_ROTATION
from modules.lidar_logger.mtdata import Pose, encode_pose_payload
from modules.lidar_logger.sim import LdmrsOptions, LdmrsSimulator, MTiGSimulator, World
from modules.lidar_logger.xbus import MID, build_frame

BAD_SCAN_EVERY = 4
BAD_POSE_EVERY = 7


@pytest.fixture
def sims() -> Iterator[list]:
    """Simulators started by the test, all stopped at the end (also on failure)."""
    started: list = []
    try:
        yield started
    finally:
        for sim in started:
            sim.stop()


def spoil_scans(sim) -> list[int]:  # noqa: ANN001
    """Every BAD_SCAN_EVERY-th scan the simulator sends goes out with a ticks-per-rotation no LD-MRS uses."""
    spoilt: list[int] = []
    take = sim.device.take_scan

    def take_scan(send: bool):  # noqa: ANN202
        scan = take(send)
        if scan is not None and scan.scan_number % BAD_SCAN_EVERY == 1:
            spoilt.append(scan.scan_number)
            sim.device.sent_scans.pop()
            return dataclasses.replace(scan, ticks_per_rotation=TICKS_PER_ROTATION - 520)
        return scan

    sim.device.take_scan = take_scan
    return spoilt


def spoil_poses(imu) -> list[Pose]:  # noqa: ANN001
    """Every BAD_POSE_EVERY-th MTData answer carries latitude 200° (a frame with a good checksum)."""
    spoilt: list[Pose] = []
    device = imu.device
    mtdata = device._mtdata
    calls = [0]

    def answer(t: float, record: bool) -> bytes:
        calls[0] += 1
        if not record or calls[0] % BAD_POSE_EVERY:
            return mtdata(t, record)
        pose = device.world.true_pose(t)
        bad = msgspec.structs.replace(pose, lla=(200.0, pose.lla[1], pose.lla[2]))
        spoilt.append(bad)
        return build_frame(MID.MTDATA, encode_pose_payload(bad, device.mode, device.settings, device.sample_counter))

    device._mtdata = answer
    return spoilt


def test_refused_scans_and_poses_are_reported_never_logged_nor_published(
    processes, router, sessions, sims: list, tmp_path: Path
) -> None:
    world = World(clock=ScaledClock(4.0), gps_fix_at=1.0, xkf_valid_at=2.0)
    imu = MTiGSimulator(world)
    sims.append(imu)
    imu.start()
    lidar = LdmrsSimulator(world, LdmrsOptions(return_fraction=0.05))
    sims.append(lidar)
    lidar.start()
    bad_scans = spoil_scans(lidar)
    bad_poses = spoil_poses(imu)
    s = sessions()
    lock = threading.Lock()
    codes: list[int] = []
    poses: list[Pose] = []

    def sub(slot: str, typ, sink: list, pick=lambda v: v):  # noqa: ANN001, ANN202
        decode = msgspec.msgpack.Decoder(typ).decode  # no range check: whatever arrives is seen

        def on(sample) -> None:  # noqa: ANN001
            with lock:
                sink.append(pick(decode(sample.payload.to_bytes())))
        return s.declare_subscriber(keys.slot_key("r1", "lidar_logger", slot), on)

    subs = [sub("error", ErrorReport, codes, lambda e: e.code), sub("pose", Pose, poses)]
    proc = processes.start(["-m", "modules.lidar_logger", "--robot", "r1", "--connect", f"tcp/127.0.0.1:{router}",
                            "--param", f"mtig_port={imu.port}", "--param", "ldmrs_host=127.0.0.1",
                            "--param", f"ldmrs_port={lidar.port}", "--param", "vehicle=CB5000",
                            "--param", f"out_dir={tmp_path}", "--param", "binary_log=true"])
    try:
        wait_until(lambda: LidarLoggerError.POSE_REFUSED in codes, 60, "a refused pose on the ERROR slot")
        wait_until(lambda: codes.count(LidarLoggerError.SCAN_REFUSED) >= 3, 90, "refused scans on the ERROR slot")
        wait_until(lambda: len(lidar.device.sent_scans) >= 3 * len(bad_scans) // 2, 60, "good scans too")
    finally:
        code = stop_process(proc, grace_s=20)
        for x in subs:
            x.undeclare()
    assert code == 0
    assert bad_scans and bad_poses
    with lock:
        published = list(poses)
    assert published and all(abs(p.lla[0]) <= 90 for p in published), "a refused pose reached the bus"
    scans, _, _ = read_binary_records(next(tmp_path.glob(f"Scan_*/LogFile_*{SCANS_SUFFIX}")))
    logged = set(np.asarray(scans["scan_number"]).tolist())
    assert logged, "nothing was logged"
    assert not logged & set(bad_scans), "a refused scan was logged"
    good = {s.scan_number for s in lidar.device.sent_scans}
    assert logged <= good
