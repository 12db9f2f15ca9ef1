"""The lidar logger as a bus module on a real router: poses and status out, a run logged, clean stop."""

from __future__ import annotations

import threading

import msgspec

from bbcs import keys
from bbcs.contracts.errors import ErrorReport
from bbcs.errors import EXIT_CONFIG
from bbcs.testing import stop_process, wait_until
from modules.lidar_logger.config import read_config_file
from modules.lidar_logger.ldmrs_proto import Cmd
from modules.lidar_logger.module import LIDAR_RUN_FAILED, LidarStatus
from modules.lidar_logger.mtdata import Pose
from modules.lidar_logger.sim import LdmrsOptions
from modules.lidar_logger.textlog import read_text_log


def subscribe(session, slot: str, typ, into: list):
    decode = msgspec.msgpack.Decoder(typ).decode
    return session.declare_subscriber(
        keys.slot_key("r1", "lidar_logger", slot), lambda smp: into.append(decode(smp.payload.to_bytes()))
    )


def start_module(processes, router: int, *params: str):
    args = ["-m", "modules.lidar_logger", "--robot", "r1", "--connect", f"tcp/127.0.0.1:{router}"]
    for p in params:
        args += ["--param", p]
    return processes.start(args)


def test_the_module_publishes_poses_and_status_and_logs_a_run(
    processes, router, sessions, make_world, start_mtig, start_ldmrs, tmp_path
) -> None:
    world = make_world(4.0, gps_fix_at=1.0, xkf_valid_at=3.0)
    imu = start_mtig(world)
    lidar = start_ldmrs(world, LdmrsOptions(return_fraction=0.1))
    s = sessions()
    poses: list[Pose] = []
    statuses: list[LidarStatus] = []
    alive = threading.Event()
    subs = [
        subscribe(s, "pose", Pose, poses),
        subscribe(s, "status", LidarStatus, statuses),
        s.liveliness().declare_subscriber(
            keys.alive_key("r1", "lidar_logger"), lambda _: alive.set(), history=True
        ),
    ]
    proc = start_module(
        processes,
        router,
        f"mtig_port={imu.port}",
        "ldmrs_host=127.0.0.1",
        f"ldmrs_port={lidar.port}",
        "vehicle=CB5000",
        f"out_dir={tmp_path}",
        "binary_log=true",
        "mounting=0,90,0,0.1,0,-0.2",
    )
    try:
        assert alive.wait(30)
        wait_until(
            lambda: any(st.state == "measuring" and st.scans_written >= 20 for st in statuses),
            60,
            "the run to log 20 scans",
        )
        wait_until(lambda: any(p.valid for p in poses), 10, "a valid pose on the bus")
    finally:
        code = stop_process(proc, grace_s=20)
        for sub in subs:
            sub.undeclare()
    assert code == 0
    assert all(p.valid == (1 if p.status == 7 else 0) for p in poses)
    sent = {(p.utc, p.status) for _, p in imu.device.poses_sent}
    assert all((p.utc, p.status) in sent for p in poses), "the bus carries the MTi-G samples themselves"
    assert "measuring" in {st.state for st in statuses}
    run = next(tmp_path.glob("Scan_*"))
    assert statuses[-1].run == run.name
    cfg = read_config_file(next(run.glob("ConfigFile_*")))
    assert cfg["end_reason"] == "signal" and cfg["mounting_z_m"] == "-0.2" and cfg["binary_log"] == "1"
    assert lidar.device.commands[-1][1] == Cmd.STOP_MEASURE and not lidar.device.measuring
    log = read_text_log(next(p for p in run.glob("LogFile_*") if not p.name.endswith(".bin")))
    assert log.n_scans == int(cfg["scans_written"]) >= 20


def test_a_failed_run_is_reported_on_the_error_slot_and_the_module_stays_up(
    processes, router, sessions, tmp_path
) -> None:
    s = sessions()
    errors: list[ErrorReport] = []
    statuses: list[LidarStatus] = []
    subs = [subscribe(s, "error", ErrorReport, errors), subscribe(s, "status", LidarStatus, statuses)]
    proc = start_module(
        processes,
        router,
        f"mtig_port={tmp_path / 'ttyUSB7'}",
        "ldmrs_host=127.0.0.1",
        "vehicle=PILATUS_PORTER",
        f"out_dir={tmp_path}",
    )
    try:
        wait_until(
            lambda: any(st.state == "finished" for st in statuses), 30, "the failed run's final status"
        )
        wait_until(lambda: errors, 10, "the error code")
        assert proc.poll() is None, "the module stays up after its run ended"
    finally:
        code = stop_process(proc, grace_s=20)
        for sub in subs:
            sub.undeclare()
    assert code == 0
    assert errors[0].code == LIDAR_RUN_FAILED
    final = next(st for st in statuses if st.state == "finished")
    assert final.end_reason == "error" and final.run == "" and final.pose_status == -1


def test_bad_settings_stop_the_module_before_it_starts(processes, router) -> None:
    """A bad param is a configuration error: exit 78 (EXIT_CONFIG), which the manager never restarts."""
    proc = start_module(processes, router, "vehicle=Cessna", "mtig_port=/dev/null", "ldmrs_host=127.0.0.1")
    assert proc.wait(30) == EXIT_CONFIG
    proc2 = start_module(
        processes, router, "vehicle=CB5000", "mtig_port=/dev/null", "ldmrs_host=x", "wingspan=12"
    )
    assert proc2.wait(30) == EXIT_CONFIG


def test_corrupt_mtig_frames_are_reported_coalesced_on_the_error_slot(
    processes, router, sessions, make_world, start_mtig, start_ldmrs, tmp_path
) -> None:
    """A burst of MTData with bad checksums (written by hand) on the MTi-G line while the module runs: reported on
    its ERROR slot as POSE_REFUSED, a few reports for forty frames (coalesced), and the poses go on."""
    from bbcs.contracts.error_codes import LidarLoggerError

    world = make_world(6.0, gps_fix_at=0.0, xkf_valid_at=0.0)
    imu = start_mtig(world)
    lidar = start_ldmrs(world, LdmrsOptions(return_fraction=0.1))
    s = sessions()
    errors: list[ErrorReport] = []
    poses: list[Pose] = []
    subs = [subscribe(s, "error", ErrorReport, errors), subscribe(s, "pose", Pose, poses)]
    proc = start_module(processes, router, f"mtig_port={imu.port}", "ldmrs_host=127.0.0.1",
                        f"ldmrs_port={lidar.port}", "vehicle=CB5000", f"out_dir={tmp_path}")
    try:
        wait_until(lambda: len(poses) >= 5, 60, "poses on the bus")
        corrupt = bytes((0xFA, 0xFF, 0x32, 3, 1, 2, 3, 0x00))  # the checksum should be 0xC6
        for _ in range(4):
            imu.inject(corrupt * 10)
        wait_until(lambda: errors, 10, "the first report")
        seen = len(poses)
        wait_until(lambda: len(poses) > seen + 5, 10, "poses after the burst")
    finally:
        stop_process(proc, grace_s=20)
        for sub in subs:
            sub.undeclare()
    refused = [e for e in errors if e.code == LidarLoggerError.POSE_REFUSED]
    assert refused and len(refused) <= 4, errors
