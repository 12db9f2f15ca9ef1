"""The simulator's IMU end over a real pty (ASCII) and TCP (binary), and the seed's fake mode: a raw log recorded
from the port replayed through the same parser and loop body."""

import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from modules.uquad.calibration import load_calibration
from modules.uquad.config import load_config
from modules.uquad.core import FlightCore
from modules.uquad.imu_protocol import ImuParser
from modules.uquad.transport import Stream

ROOT = Path(__file__).resolve().parents[3]
CONF = ROOT / "bbcs_conf" / "uquad1.conf"


@pytest.fixture
def sim(request):
    args = request.param
    proc = subprocess.Popen([sys.executable, "-m", "modules.uquad.sim", "--conf", str(CONF), "--speed", "5",
                             "--gps", "none", "--truth", "none", *args], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        yield proc.stdout.readline()
    finally:
        proc.terminate()
        proc.wait(10)


def read_frames(stream: Stream, parser: ImuParser, n: int, record: bytearray | None = None) -> list:
    frames: list = []
    end = time.monotonic() + 30
    while len(frames) < n and time.monotonic() < end:
        data = stream.read()
        if record is not None:
            record += data
        frames += parser.feed(data)
        time.sleep(0.005)
    return frames


@pytest.mark.parametrize("sim", [["--imu", "pty", "--imu-mode", "ascii"]], indirect=True)
def test_ascii_frames_over_a_pty(sim):
    path = re.search(r"imu=(/dev/\S+)", sim).group(1)
    stream = Stream(path, 115200)
    parser = ImuParser("ascii")
    try:
        frames = read_frames(stream, parser, 100)
    finally:
        stream.close()
    assert len(frames) >= 100
    assert parser.stats.bad_frames <= 1  # at most the line we joined in the middle of
    assert all(90_000 < f.pressure_pa < 110_000 and 9_000 <= f.loop_us < 10_000 for f in frames)


@pytest.mark.parametrize("sim", [["--imu", "127.0.0.1:0"]], indirect=True)
def test_recorded_raw_log_replays_through_the_loop(sim, tmp_path):
    port = re.search(r"imu=tcp://127.0.0.1:(\d+)", sim).group(1)
    stream = Stream(f"tcp://127.0.0.1:{port}")
    raw = bytearray()
    try:
        live = read_frames(stream, ImuParser("binary"), 600, raw)
    finally:
        stream.close()
    log = tmp_path / "imu_raw.bin"
    log.write_bytes(bytes(raw))
    cfg = load_config(CONF)
    core = FlightCore(cfg, load_calibration(cfg.imu_calib_file))
    replay = Stream(f"file://{log}")
    parser = ImuParser("binary")
    frames = []
    try:
        with pytest.raises(EOFError):
            while True:
                frames += parser.feed(replay.read())
    finally:
        replay.close()
    assert frames == live[:len(frames)] and len(frames) >= 600
    for i, frame in enumerate(frames):
        core.on_imu(frame, i * 0.01)
    assert core.calibrated and core.stats.calibration_refusals == 0
    assert abs(core.kalman.euler[0]) < 0.05 and abs(core.kalman.euler[1]) < 0.05  # standing level


def test_the_frames_that_arrive_with_the_end_of_the_stream_are_read(tmp_path):
    """The flight loop's read (``read_available``): a recorded raw log arrives with its end in the same read, and so
    do a simulator's last frames before it closes; all of them come back with the end, none is lost."""
    import socket

    from modules.uquad.geo import Home
    from modules.uquad.imu_protocol import encode_binary
    from modules.uquad.sim.quad import QuadSim
    from modules.uquad.transport import read_available

    cfg = load_config(CONF)
    sim = QuadSim(cfg.quad, load_calibration(cfg.imu_calib_file), Home(cfg.home_lat, cfg.home_lon, cfg.home_alt))
    wire = b"".join(encode_binary(sim.imu_frame()) for _ in range(500))
    log = tmp_path / "imu_raw.bin"
    log.write_bytes(wire)
    replay = Stream(f"file://{log}")
    try:
        data, end = read_available(replay)
    finally:
        replay.close()
    assert isinstance(end, EOFError) and data == wire
    assert len(ImuParser("binary").feed(data)) == 500

    with socket.create_server(("127.0.0.1", 0)) as server:
        stream = Stream(f"tcp://127.0.0.1:{server.getsockname()[1]}")
        far, _ = server.accept()
        far.sendall(wire)
        far.close()  # the simulator's end: its last frames, then the close
        got, end = b"", None
        try:
            deadline = time.monotonic() + 10
            while end is None and time.monotonic() < deadline:
                data, end = read_available(stream)
                got += data
        finally:
            stream.close()
    assert isinstance(end, EOFError) and got == wire


def test_lockstep_sends_the_next_imu_frame_only_after_the_set_point_answering_the_last():
    """``--lockstep`` (the shipped uquad1_sim.toml): on the clock (here 50× real time) until the ESC link answers,
    then one IMU frame per ESC set-point however slowly the set-points come; a controller that stops answering is
    waited for 5 × the answer timeout (1 s here, 0.5 s shipped), then the simulator runs on the clock again."""
    import socket

    from modules.uquad import motor_protocol as mp

    proc = subprocess.Popen([sys.executable, "-m", "modules.uquad.sim", "--conf", str(CONF), "--speed", "50",
                             "--gps", "none", "--truth", "none", "--lockstep", "--answer-timeout", "1"],
                            stdout=subprocess.PIPE, text=True, cwd=ROOT)
    imu = esc = None
    try:
        ready = proc.stdout.readline()
        imu = Stream(re.search(r"imu=(tcp://127.0.0.1:\d+)", ready).group(1))
        esc = socket.create_connection(("127.0.0.1", int(re.search(r"esc=tcp://127.0.0.1:(\d+)", ready).group(1))))
        parser = ImuParser("binary")

        def frames_within(seconds: float, enough: int | None = None) -> int:
            got, end = 0, time.monotonic() + seconds
            while time.monotonic() < end and (enough is None or got < enough):
                got += len(parser.feed(imu.read()))
                time.sleep(0.002)
            return got

        assert frames_within(0.3) > 100  # on the clock: 50 × 100 frames a second, nobody answering yet
        esc.sendall(mp.esc([0.0] * 4))  # the first set-point: the simulator waits on the link from now on
        frames_within(0.2)  # what was in flight
        per_answer = []
        for _ in range(20):
            esc.sendall(mp.esc([0.0] * 4))
            # the frame it answers, then 0.05 s more: 250 frames at 50× had the simulator not waited
            per_answer.append(frames_within(5.0, enough=1) + frames_within(0.05))
        assert per_answer == [1] * 20, per_answer
        assert frames_within(0.3) == 0  # no answer: it waits (up to 1 s a frame) ...
        assert frames_within(6.0) > 100  # ... five times, then it runs on the clock again
    finally:
        for end in (imu, esc):
            if end is not None:
                end.close()
        proc.terminate()
        out, _ = proc.communicate(timeout=10)
    assert "no ESC answer to 5 frames: on the clock again" in out
    assert re.search(r"lockstep_waits=(\d+) lockstep_timeouts=(\d+)", out).group(2) == "5"
