"""The lidar simulators and the logger in a lockstep simulation (docs/lidar_logger.md §8, docs/simulation.md).

The devices' lockstep rules are checked directly (the MTi-G's held ReqData, the LD-MRS's release grid, the step
clock); then whole runs through the real pty and TCP links, stepped by the real ``Barrier`` over both ends'
answers (no bus: the stepper's part is played here), give the same log whichever of the logger's reading threads
is slowed down: the race the barrier and the logger's lockstep rules remove.
"""

from __future__ import annotations

import os
import random
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from bbcs.clock import SimClock, SimTime
from bbcs.lockstep import Barrier, Done, Verdict
from modules.lidar_logger.binlog import read_binary_log
from modules.lidar_logger.clock import RobotClock
from modules.lidar_logger.ldmrs_proto import Cmd, command_payload
from modules.lidar_logger.logger import LidarLogger, LoggerSettings
from modules.lidar_logger.sim import Flight, LdmrsOptions, LdmrsSimulator, MTiGSimulator, World
from modules.lidar_logger.sim.ldmrs_sim import LdmrsDevice
from modules.lidar_logger.sim.lockstep import SAMPLE_PERIOD_S, StepClock, server_state
from modules.lidar_logger.sim.mtig_sim import MTiGDevice
from modules.lidar_logger.xbus import MID, Frame

STEP_S = 0.2


def step_world(**kw) -> World:
    return World(clock=StepClock(), flight=Flight(speed=15.0, height=60.0), gps_fix_at=0.4, xkf_valid_at=0.8, **kw)


def test_the_mtig_answers_each_request_with_its_next_sample_once_the_clock_reaches_it() -> None:
    world = step_world()
    device = MTiGDevice(world, sample_period=SAMPLE_PERIOD_S)
    assert device.handle(Frame(MID.REQ_DATA, b""), 0.013) == []  # held, whatever the wall does meanwhile
    assert device.pending == 1 and device.next_index == 1  # the grid's next instant: 0.02 s
    assert not device.answerable(0.013)
    assert device.answerable(0.02 - 1e-9)  # sums of 0.02 s physics steps drift: the same instant
    device.answer_held()
    assert [round(t, 9) for t, _ in device.poses_sent] == [0.02]
    for _ in range(3):  # requests come faster than simulated time: answered one grid instant after another
        device.handle(Frame(MID.REQ_DATA, b""), 0.02)
    answered = []
    for now in (0.02, 0.05, 0.2):
        while device.answerable(now):
            device.answer_held()
            answered.append(round(device.poses_sent[-1][0], 9))
        answered.append(f"at {now}")
    assert answered == ["at 0.02", 0.04, "at 0.05", 0.06, 0.08, "at 0.2"]
    assert device.pending == 0
    # without the grid (free running) a request is answered at once with the pose at that time
    free = MTiGDevice(world)
    assert len(free.handle(Frame(MID.REQ_DATA, b""), 0.013)) == 1 and free.poses_sent[0][0] == 0.013


def test_a_scan_leaves_at_the_first_sample_instant_after_its_end() -> None:
    world = step_world()
    grid = LdmrsDevice(world, LdmrsOptions(release_grid=SAMPLE_PERIOD_S))
    free = LdmrsDevice(world, LdmrsOptions())
    for device in (grid, free):
        device.handle_command(command_payload(Cmd.START_MEASURE), 1.0)
    end = grid.next_due()
    assert end is not None and end == pytest.approx(1.0 + 0.5 * grid.period + grid.sweep)  # 1.0622 s
    release = np.ceil(end / SAMPLE_PERIOD_S) * SAMPLE_PERIOD_S  # 1.08 s
    assert free.due(end) and not grid.due(end)
    assert not grid.due(release - 1e-3) and grid.due(release) and grid.due(release - 1e-9)


def test_the_step_clock_moves_only_to_a_step_whose_truth_has_come_and_wakes_its_servers() -> None:
    clock = StepClock()
    fd = clock.subscribe()
    assert clock.has_truth(0.0) and not clock.has_truth(0.2)
    clock.on_truth(0.18, 1.0)
    assert not clock.has_truth(0.2) and not clock.wait_truth(0.2, 0.01)
    clock.on_truth(0.2 - 1e-12, 1.0)  # ten sums of 0.02
    assert clock.has_truth(0.2) and clock.now() == 0.0  # the truth alone does not move it: the ask does
    assert clock.advance(0.2) and clock.now() == 0.2
    assert len(os.read(fd, 16)) == 1
    assert not clock.advance(0.1) and clock.now() == 0.2  # never backwards


# --- whole runs through the real links, stepped by the barrier ---------------------------------------------------


def run_stepped(out: Path, steps: int, slow: str | None, seed: int) -> dict[str, np.ndarray]:
    """A lockstep run of ``steps`` steps; ``slow`` ("pose" or "scan") sleeps at random in that reading thread."""
    world = step_world()
    clock = world.clock
    assert isinstance(clock, StepClock)
    robot = SimClock(epoch=1000.0)
    rng = random.Random(seed)

    def nap(_item: object) -> None:
        time.sleep(rng.uniform(0.0, 0.01))

    imu = MTiGSimulator(world, sample_period=SAMPLE_PERIOD_S).start()
    lidar = LdmrsSimulator(world, LdmrsOptions(release_grid=SAMPLE_PERIOD_S, return_fraction=0.25)).start()
    logger = LidarLogger(LoggerSettings(mtig_port=imu.port, ldmrs_host=lidar.host, ldmrs_port=lidar.port,
                                        out_dir=out, binary=True, text=False, progress=False,
                                        mounting=world.mounting),
                         clock=RobotClock(robot), lockstep=True,
                         on_pose=nap if slow == "pose" else None, on_scan=nap if slow == "scan" else None)
    sims = server_state(imu, lidar)
    thread = threading.Thread(target=logger.run, daemon=True)
    barrier = Barrier(deadline_s=30.0)
    barrier.joined("lidar_sim")
    barrier.joined("lidar_logger")
    try:
        thread.start()
        for step in range(steps):
            t = step * STEP_S
            clock.on_truth(t, 1.0)
            clock.advance(t)
            robot.advance(SimTime(step=step, t=t, epoch=1000.0))
            barrier.begin(step, time.monotonic())
            while True:  # the stepper's rounds: both members answer, the barrier decides
                busy, counts = sims(clock.now())
                barrier.answer(Done(member="lidar_sim", step=step, round=barrier.round, activity=0, busy=busy,
                                    counts=counts))
                barrier.answer(Done(member="lidar_logger", step=step, round=barrier.round, activity=0,
                                    busy=logger.lockstep_busy(), counts=logger.lockstep_counts()))
                decision = barrier.decide(time.monotonic())
                assert not decision.left_behind, decision.why
                if decision.verdict is Verdict.STEP:
                    break
                time.sleep(max(decision.delay, 0.001))
    finally:
        logger.request_stop("signal")
        thread.join(timeout=30)
        lidar.stop()
        imu.stop()
    assert logger.summary.reason == "signal", logger.summary
    assert logger.summary.binary_paths is not None
    log = read_binary_log(logger.summary.binary_paths[0])
    return {"scan_number": log.scan_number, "end_time": log.end_time, "pose_time": log.pose_time,
            "lla": log.lla, "euler": log.euler, "n_points": log.n_points, "xyz": log.xyz}


def test_a_stepped_run_logs_the_same_scans_and_poses_whichever_reading_thread_is_slow(tmp_path: Path) -> None:
    steps = 25  # 5 simulated seconds: the first valid pose at 0.8 s, then 4 s of scans
    runs = [run_stepped(tmp_path / name, steps, slow, seed) for name, slow, seed in
            (("plain", None, 1), ("slow_pose", "pose", 2), ("slow_scan", "scan", 3))]
    first = runs[0]
    n = len(first["end_time"])
    assert n >= 12.5 * 4.0 * 0.9, n  # every rotation, none dropped
    assert np.all(np.diff(first["scan_number"]) == 1)
    # each scan carries the newest 20-ms sample at or before its end
    lag = first["end_time"] - first["pose_time"]
    assert np.all(lag >= 0) and np.all(lag < SAMPLE_PERIOD_S), lag
    for other in runs[1:]:
        for name, values in first.items():
            assert np.array_equal(values, other[name]), name


def test_the_logger_answers_busy_while_it_configures_and_reports_both_links(tmp_path: Path) -> None:
    world = step_world()
    clock = world.clock
    assert isinstance(clock, StepClock)
    robot = SimClock(epoch=1000.0)
    imu = MTiGSimulator(world, sample_period=SAMPLE_PERIOD_S).start()
    lidar = LdmrsSimulator(world, LdmrsOptions(release_grid=SAMPLE_PERIOD_S, return_fraction=0.1)).start()
    logger = LidarLogger(LoggerSettings(mtig_port=imu.port, ldmrs_host=lidar.host, ldmrs_port=lidar.port,
                                        out_dir=tmp_path, progress=False), clock=RobotClock(robot), lockstep=True)
    assert logger.lockstep_busy() == "configuring the MTi-G" and logger.lockstep_counts() == {}
    thread = threading.Thread(target=logger.run, daemon=True)
    try:
        thread.start()
        deadline = time.monotonic() + 20
        while logger.state != "waiting_pose" or logger.lockstep_busy():
            assert time.monotonic() < deadline, logger.state
            time.sleep(0.01)
        # simulated time stands at 0: no valid pose, the poll's request held by the MTi-G, nothing else to do
        assert set(logger.lockstep_counts()) == {f"wire/mtig:{imu.port}/tx", f"wire/mtig:{imu.port}/rx"}
        clock.advance(1.0)  # past the valid pose: the logger holds the step while it configures the scanner
        robot.advance(SimTime(step=1, t=1.0, epoch=1000.0))
        busy_seen = set()
        while logger.state != "measuring":
            busy_seen.add(logger.lockstep_busy())
            assert time.monotonic() < deadline, logger.state
            time.sleep(0.001)
        assert busy_seen & {"a valid pose: configuring the LD-MRS", "configuring the LD-MRS"}, busy_seen
        start = [t for t, cmd, _, _ in lidar.device.commands if cmd == Cmd.START_MEASURE]
        assert start == [1.0]  # StartMeasure at the step's instant, not wherever the wall had got to
        assert f"wire/ldmrs:{lidar.host}:{lidar.port}/rx" in logger.lockstep_counts()
    finally:
        logger.request_stop("signal")
        thread.join(timeout=30)
        lidar.stop()
        imu.stop()
    assert logger.summary.first_valid_pose_t == 1.0  # received at the step's simulated time
