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


def test_on_the_bus_barrier_a_step_waits_for_every_member_and_every_byte_on_the_device_links():
    """``CROMAT_SIM`` in its environment (a lockstep launch): the simulator process is the robot's stepper on a real
    router. Nothing moves while the manager holds the first step, nor before the IMU link has a reader; then each
    step of 0.1 simulated s writes its 10 IMU frames and waits until the flight module (a stand-in here, answering
    with the bytes it has read) has handled all of them, and, once set-points flow, until each command sent has
    arrived as a set-point. The truth carries the simulated time as the robot's clocks read it."""
    import json
    import socket
    import threading

    from bbcs.clock import SimClock
    from bbcs.lockstep import MANAGER_MEMBER, Member, SimSettings, settings_env
    from bbcs.session import local_client, open_session
    from bbcs.testing import Processes, child_env, start_router, wait_until
    from modules.uquad import motor_protocol as mp
    from modules.uquad.lockstep import IMU_KEY, MOTOR_KEY

    robot = "r1"
    frame_b = 28  # a binary IMU frame

    class StandIn:
        """A member answering every ask (unless held) with the counts ``counts()`` gives at that moment."""

        def __init__(self, session, name, counts=dict) -> None:  # noqa: ANN001 - a test double
            self.clock = SimClock()
            self.hold = threading.Event()
            self.held = []
            self.counts = counts
            self.member = Member(session, robot, name, self._on_ask)

        def _on_ask(self, ask) -> None:  # noqa: ANN001
            self.clock.advance(ask.now)
            if self.hold.is_set():
                self.held.append(ask)
                return
            self.member.answer(ask, 0, counts=self.counts())

    procs = Processes()
    sessions = []
    imu = esc = truth = None
    try:
        port = start_router(procs)
        sessions = [open_session(local_client(port)) for _ in range(2)]
        manager = StandIn(sessions[0], MANAGER_MEMBER)
        manager.hold.set()
        settings = SimSettings(robot=robot, connect=[f"tcp/127.0.0.1:{port}"], speed="max", step_s=0.1)
        sim = procs.start(["-m", "modules.uquad.sim", "--conf", str(CONF), "--gps", "none"],
                          env=child_env(**settings_env(settings)), stdout=subprocess.PIPE, text=True)
        ready = sim.stdout.readline()
        assert "uquad sim ready" in ready, ready
        ports = {name: int(p) for name, p in re.findall(r"(\w+)=tcp://127.0.0.1:(\d+)", ready)}
        wait_until(lambda: manager.held, 10, "the first ask")
        truth = socket.create_connection(("127.0.0.1", ports["truth"]))
        truth.settimeout(10)
        manager.hold.clear()
        manager.member.answer(manager.held[-1], 0)
        time.sleep(0.5)
        assert manager.clock.monotonic() == 0.0, "stepped before the IMU link had a reader"

        handled = {"imu": 0, "sent": 0}
        uquad = StandIn(sessions[1], "uquad", lambda: {IMU_KEY: handled["imu"], MOTOR_KEY: handled["sent"]})
        time.sleep(0.3)  # its token seen by the stepper before the IMU link connects
        imu = Stream(f"tcp://127.0.0.1:{ports['imu']}")
        received = bytearray()

        def read_for(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                received.extend(imu.read())
                time.sleep(0.005)

        for step in range(1, 4):  # each step: its 10 frames, then nothing until the stand-in has handled them
            read_for(0.5)
            assert len(received) == step * 10 * frame_b, (step, len(received))
            assert abs(uquad.clock.monotonic() - step * 0.1) < 1e-9
            assert abs(manager.clock.monotonic() - step * 0.1) < 1e-9
            handled["imu"] = len(received)

        # set-points: a command the flight module has sent whose set-point has not arrived holds the step
        handled["sent"] = 1
        read_for(0.5)
        handled["imu"] = len(received)  # the IMU side handled: only the ESC link holds the step now
        read_for(0.5)
        at, got = manager.clock.monotonic(), len(received)
        read_for(0.5)
        assert (manager.clock.monotonic(), len(received)) == (at, got), "stepped before the driver connected"
        esc = socket.create_connection(("127.0.0.1", ports["esc"]))
        read_for(0.5)
        assert (manager.clock.monotonic(), len(received)) == (at, got), "stepped with a set-point on its way"
        esc.sendall(mp.esc([0.0] * 4))  # the set-point arrives: the step settles, and from now on each frame waits
        for _ in range(25):  # the device links' lockstep inside the steps: one frame per set-point
            before = len(received)
            wait_until(lambda n=before: bool(received.extend(imu.read()) or len(received) > n), 10, "the next frame")
            assert len(received) == before + frame_b
            handled["imu"] = len(received)
            handled["sent"] += 1
            esc.sendall(mp.esc([0.0] * 4))
        assert abs(manager.clock.monotonic() - (at + 0.2)) < 1e-9  # two whole steps of 10 frames, the third waits

        buf = b""
        while buf.count(b"\n") < 3:
            buf += truth.recv(65536)
        line = json.loads(buf.split(b"\n")[2])
        epoch = manager.clock.time() - manager.clock.monotonic()
        assert abs(line["stamp"] - (epoch + line["t"])) < 1e-3, (line["stamp"], line["t"], epoch)
    finally:
        for end in (imu, esc, truth):
            if end is not None:
                end.close()
        for s in sessions:
            s.close()
        procs.stop_all()


def test_a_uquad_simulator_refuses_a_lockstep_fleet() -> None:
    """Not built (docs/simulation.md): said at start, before any device end is opened."""
    from bbcs.lockstep import SimSettings, settings_env
    from bbcs.testing import child_env

    env = {**child_env(), **settings_env(SimSettings(robot="uquad1", fleet=["uquad1", "uav2"]))}
    run = subprocess.run([sys.executable, "-m", "modules.uquad.sim", "--conf", str(CONF)], env=env,
                         capture_output=True, text=True, timeout=60, cwd=str(ROOT))
    assert run.returncode == 2 and "a uQuad in a lockstep fleet ([sim] fleet) is not built" in run.stderr
    assert "uquad sim ready" not in run.stdout
