"""Motor driver: refuses out-of-range values, ramps at start, acks every command, stops when commands stop;
the process tested across real TCP links with an ESC recorder at the far end."""

import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from modules.uquad import motor_protocol as mp
from modules.uquad.config import load_config
from modules.uquad.motor_client import RECOVERY_S, MotorClient
from modules.uquad.motor_driver import DriverLogic, DriverState
from modules.uquad.motor_protocol import AckStatus

ROOT = Path(__file__).resolve().parents[3]
SHIPPED_ACK_TIMEOUT = load_config(ROOT / "bbcs_conf" / "uquad1.conf").values.MOTOR_ACK_TIMEOUT


def logic() -> DriverLogic:
    return DriverLogic(min_speed=300, max_speed=750, ramp_s=1.0, cmd_timeout_s=0.2)


def test_out_of_range_refused_and_previous_kept():
    d = logic()
    assert d.on_command(0.0, (400, 400, 400, 400)) is AckStatus.RAMPING
    for bad in ((299, 400, 400, 400), (400, 400, 751, 400), (0, 400, 400, 400)):
        assert d.on_command(0.05, bad) is AckStatus.OUT_OF_RANGE
    assert d.refused == 3 and d.target == [400] * 4


def test_ramp_from_zero_to_min_jumping_around_it_then_commands():
    d = logic()
    d.on_command(0.0, (500, 500, 500, 500))
    values = []
    for i in range(1, 10):
        d.on_command(i * 0.1, (500, 500, 500, 500))  # keep commanding
        values.append(d.output(i * 0.1)[0])
    assert all(0 <= v <= 300 for v in values)
    assert values[-1] > values[0]  # rising
    assert any(values[i] > values[i + 1] for i in range(len(values) - 1))  # jumps below the ramp too
    assert d.on_command(1.0, (500, 510, 520, 530)) is AckStatus.OK
    assert d.output(1.0) == [500, 510, 520, 530] and d.state is DriverState.RUNNING


def test_motors_stop_when_commands_stop_and_on_stop_command():
    d = logic()
    d.on_command(0.0, (400,) * 4)
    d.on_command(1.1, (400,) * 4)
    assert d.output(1.2) == [400] * 4
    assert d.output(1.31) == [0.0] * 4 and d.timeouts == 1 and d.state is DriverState.STOPPED
    d.on_command(2.0, (400,) * 4)
    assert d.on_command(2.05, (0, 0, 0, 0)) is AckStatus.STOPPED and d.output(2.06) == [0.0] * 4


class EscRecorder:
    """The ESCs' far end: records every set-point frame the driver sends."""

    def __init__(self) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.conn: socket.socket | None = None
        self.parser = mp.FrameParser("E")
        self.frames: list[tuple[float, ...]] = []

    def pump(self, until: float) -> None:
        while time.monotonic() < until:
            if self.conn is None:
                self.listener.settimeout(max(0.01, until - time.monotonic()))
                try:
                    self.conn, _ = self.listener.accept()
                except TimeoutError:
                    continue
                self.conn.settimeout(0.02)
            try:
                data = self.conn.recv(4096)
            except TimeoutError:
                continue
            self.frames += [mp.speeds(f) for f in self.parser.feed(data)]

    def close(self) -> None:
        if self.conn:
            self.conn.close()
        self.listener.close()


def start_driver(tmp_path, *extra: str) -> tuple[subprocess.Popen, "EscRecorder", int]:
    conf = tmp_path / "u.conf"
    text = (ROOT / "bbcs_conf" / "uquad1.conf").read_text()
    for old, new in (("MOTOR_RAMP_S: 1.5", "MOTOR_RAMP_S: 0.3"), ("MOTOR_CMD_TIMEOUT: 0.5", "MOTOR_CMD_TIMEOUT: 0.2")):
        assert old in text
        text = text.replace(old, new)
    conf.write_text(text)
    esc = EscRecorder()
    proc = subprocess.Popen([sys.executable, "-m", "modules.uquad.motor_driver", "--conf", str(conf), "--esc",
                             f"127.0.0.1:{esc.port}", *extra], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    line = proc.stdout.readline()
    match = re.search(r"tcp://127.0.0.1:(\d+)", line)
    if match is None:
        proc.kill()
        esc.close()
        raise AssertionError(f"no ready line from the driver: {line!r}")
    return proc, esc, int(match.group(1))


@pytest.fixture
def driver(tmp_path):
    proc, esc, port = start_driver(tmp_path)
    try:
        yield esc, port
    finally:
        proc.terminate()
        proc.wait(10)
        esc.close()


def test_lockstep_driver_sends_one_set_point_per_command_timed_by_the_commands(tmp_path):
    """``--lockstep``: no keep-alive, one ESC frame per command (a refused one too: the last good set-point), and
    the ramp (0.3 s here) lasts 30 commands of 10 ms however slowly they come."""
    proc, esc, port = start_driver(tmp_path, "--lockstep")
    ack_timeout = load_config(ROOT / "bbcs_conf" / "uquad1.conf").values.MOTOR_ACK_TIMEOUT  # the shipped 0.5 s
    client = MotorClient(socket.create_connection(("127.0.0.1", port)), 300, 750, ack_timeout_s=ack_timeout)
    try:
        for i in range(40):
            client.sock.send(mp.command(i, [500, 500, 500, 500]))
            esc.pump(time.monotonic() + (0.03 if i < 5 else 0.005))  # slower than 10 ms a command at first
        client.sock.send(mp.command(40, [100, 500, 500, 500]))  # out of range: refused, last good set-point
        esc.pump(time.monotonic() + 0.5)  # and half a second of silence: nothing more is sent
        client.on_readable(time.monotonic())
        assert len(esc.frames) == 41, len(esc.frames)
        ramp = esc.frames[:29]
        assert all(len(set(f)) == 1 and f[0] <= 300 for f in ramp)  # ramping for 0.3 s of commands
        assert esc.frames[31:40] == [(500.0,) * 4] * 9  # running from the 31st or 32nd command on
        assert esc.frames[40] == (500.0,) * 4
        assert "OUT_OF_RANGE" in client.check(time.monotonic())
    finally:
        client.close()
        proc.terminate()
        proc.wait(10)
        esc.close()


def test_driver_process_end_to_end(driver):
    esc, port = driver
    client = MotorClient(socket.create_connection(("127.0.0.1", port)), 300, 750, ack_timeout_s=0.5)
    try:
        # commands every 20 ms for 0.6 s: ramp (0.3 s) then the commanded speeds reach the ESCs
        for _ in range(30):
            t = time.monotonic()
            sent = client.send(t, [900, 500, 200, 500])  # the client clamps: 750, 500, 300, 500
            esc.pump(t + 0.02)
            client.on_readable(time.monotonic())
        assert sent == [750, 500, 300, 500]
        assert client.acks >= 25 and client.check(time.monotonic()) == ""
        ramp = [f[0] for f in esc.frames if f[0] <= 300 and len(set(f)) == 1]
        assert ramp and max(ramp) <= 300
        assert esc.frames[-1] == (750, 500, 300, 500)
        # an out-of-range value sent raw (bypassing the clamp) is refused: the ESCs keep the last good set-point
        client.sock.send(mp.command(999, [100, 500, 500, 500]))
        esc.pump(time.monotonic() + 0.1)
        client.on_readable(time.monotonic())
        assert "OUT_OF_RANGE" in client.check(time.monotonic())
        assert esc.frames[-1] == (750, 500, 300, 500)
        # commands stop: the driver stops the motors within MOTOR_CMD_TIMEOUT (0.2 s) + a send period
        esc.pump(time.monotonic() + 0.4)
        assert esc.frames[-1] == (0.0, 0.0, 0.0, 0.0)
    finally:
        client.close()


def test_missing_ack_is_a_driver_error():
    a, b = socket.socketpair()
    client = MotorClient(a, 300, 750, ack_timeout_s=0.1)
    client.send(10.0, [400] * 4)
    assert client.check(10.05) == ""
    assert "no ack" in client.check(10.2)
    b.close()
    a.close()


def _answer(b: socket.socket, client: MotorClient, now: float, status: AckStatus = AckStatus.STOPPED) -> None:
    """The driver's end: ack every command the client sent so far, and let the client read them."""
    for seq in list(client.pending):
        b.sendall(mp.ack(seq, status))
    deadline = time.monotonic() + 5
    while client.pending and time.monotonic() < deadline:
        client.on_readable(now)
    assert not client.pending, "the acks did not arrive"


def test_a_late_ack_clears_after_acks_in_time_and_any_other_error_stays():
    a, b = socket.socketpair()
    client = MotorClient(a, 300, 750, ack_timeout_s=SHIPPED_ACK_TIMEOUT)
    late = SHIPPED_ACK_TIMEOUT + 0.1
    try:
        client.send(0.0, [0.0] * 4)
        assert "no ack for command 1" in client.check(late)  # late: a loaded computer, or a dead driver
        _answer(b, client, late + 0.1)  # it answers after all
        t = late + 0.1
        while t < late + 0.1 + RECOVERY_S - 0.05:  # commands acknowledged in time, not yet for long enough
            client.send(t, [0.0] * 4)
            _answer(b, client, t)
            assert client.check(t) and not client.recover(t), t
            t += 0.05
        t += 0.1
        client.send(t, [0.0] * 4)
        _answer(b, client, t)
        assert client.check(t)
        assert client.recover(t) and client.check(t) == ""
        # a refusal is not a late ack: it never clears, however long the driver answers in time afterwards
        client.send(t, [400.0] * 4)
        _answer(b, client, t, AckStatus.OUT_OF_RANGE)
        assert "OUT_OF_RANGE" in client.check(t)
        for i in range(60):
            client.send(t + 0.05 * i, [0.0] * 4)
            _answer(b, client, t + 0.05 * i)
        assert not client.recover(t + 3.0) and "OUT_OF_RANGE" in client.check(t + 3.0)
    finally:
        a.close()
        b.close()


def test_an_ack_that_never_comes_never_clears():
    a, b = socket.socketpair()
    client = MotorClient(a, 300, 750, ack_timeout_s=SHIPPED_ACK_TIMEOUT)
    late = SHIPPED_ACK_TIMEOUT + 0.1
    try:
        client.send(0.0, [0.0] * 4)
        assert client.check(late)
        b.recv(4096)  # the driver read it and never answered: later commands answered do not excuse it
        for i in range(1, 80):
            client.send(late + 0.05 * i, [0.0] * 4)
            seq = client.seq
            b.sendall(mp.ack(seq, AckStatus.STOPPED))
        deadline = time.monotonic() + 5
        while len(client.pending) > 1 and time.monotonic() < deadline:
            client.on_readable(late + 4.0)
        assert list(client.pending) == [1]
        assert client.check(late + 4.0) and not client.recover(late + 4.0)
    finally:
        a.close()
        b.close()


def test_refused_commands_keep_the_motors_running_silence_stops_them():
    """A 50 Hz stream of refused commands (2 s, four times the timeout) keeps the last good set-point: the
    controller is alive and acts on the refusal itself (MOTOR_ERROR_ACTION); only silence stops the motors."""
    d = logic()  # cmd_timeout_s 0.2
    t = 0.0
    while t < 1.2:  # ramp (1 s), then running at 400
        d.on_command(t, (400,) * 4)
        t += 0.02
    assert d.state is DriverState.RUNNING and d.output(t) == [400] * 4
    statuses = set()
    for i in range(100):
        now = t + 0.02 * (i + 1)
        statuses.add(d.on_command(now, (400, 400, 9000, 400)))
        assert d.output(now) == [400] * 4, f"motors changed {now - t:.2f} s into the refusals"
    assert statuses == {AckStatus.OUT_OF_RANGE} and d.refused == 100 and d.timeouts == 0
    last = t + 2.0
    assert d.output(last + 0.19) == [400] * 4
    assert d.output(last + 0.21) == [0.0] * 4 and d.timeouts == 1
