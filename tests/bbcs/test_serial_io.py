"""``bbcs.serial_io.write_all`` on real pyserial ports (a pty, a TCP socket on 127.0.0.1): every byte written is
counted, a thread descheduled past the timeout after its write is no timeout (pyserial's own write says it is),
and a port that takes nothing more times out saying how much was left."""

from __future__ import annotations

import os
import socket
import threading
from collections.abc import Iterator

import pytest
import serial
import serial.serialutil

from bbcs.serial_io import write_all


@pytest.fixture
def pty_port() -> Iterator[tuple[serial.Serial, int]]:
    """A pyserial port on a pty's slave end, as the lidar logger opens the MTi-G's; and the master's fd."""
    master, slave = os.openpty()
    port = serial.serial_for_url(os.ttyname(slave), timeout=0.02, write_timeout=1.0)
    try:
        yield port, master
    finally:
        port.close()
        os.close(master)
        os.close(slave)


def read_all(fd: int, n: int) -> bytes:
    got = b""
    while len(got) < n:
        got += os.read(fd, n - len(got))
    return got


class JumpAfterFirstWrite:
    """A monotonic clock that jumps 30 s once the first byte has been written: a thread descheduled between its
    write and pyserial's timeout check (a machine at load 50)."""

    def __init__(self) -> None:
        self.written = False
        self.base = 1000.0

    def __call__(self) -> float:
        return self.base + (30.0 if self.written else 0.0)


def test_bytes_are_written_and_counted_through_a_pty(pty_port: tuple[serial.Serial, int]) -> None:
    port, master = pty_port
    counted: list[int] = []
    write_all(port, b"\xfa\xff\x34\x00\xcd", 1.0, counted.append)
    assert read_all(master, 5) == b"\xfa\xff\x34\x00\xcd" and sum(counted) == 5


def test_a_thread_descheduled_after_its_write_is_no_timeout(pty_port: tuple[serial.Serial, int],
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    port, master = pty_port
    clock = JumpAfterFirstWrite()
    real_write = os.write

    def write_then_sleep(fd: int, data: bytes) -> int:
        n = real_write(fd, data)
        clock.written = True
        return n

    monkeypatch.setattr(serial.serialutil.Timeout, "TIME", clock)
    monkeypatch.setattr("bbcs.serial_io.time.monotonic", clock)
    monkeypatch.setattr(os, "write", write_then_sleep)
    with pytest.raises(serial.SerialTimeoutException):  # the quirk: pyserial's own write, every byte delivered
        port.write(b"\x01\x02\x03\x04\x05")
    assert read_all(master, 5) == b"\x01\x02\x03\x04\x05"
    clock.written = False
    counted: list[int] = []
    write_all(port, b"\xfa\xff\x34\x00\xcd", 1.0, counted.append)  # the same delay: written, counted, no error
    assert read_all(master, 5) == b"\xfa\xff\x34\x00\xcd" and sum(counted) == 5


def test_a_port_that_takes_nothing_more_times_out_with_what_was_left(pty_port: tuple[serial.Serial, int]) -> None:
    port, _master = pty_port  # nobody reads the master: the pty's buffer fills
    counted: list[int] = []
    data = bytes(1 << 20)
    with pytest.raises(serial.SerialTimeoutException, match="bytes not taken by the port in 0.3 s"):
        write_all(port, data, 0.3, counted.append)
    assert 0 < sum(counted) < len(data)  # what went out is counted, the rest is not


def test_a_tcp_port_is_written_and_counted() -> None:
    server = socket.create_server(("127.0.0.1", 0))
    host, port_no = server.getsockname()
    got = bytearray()

    def serve() -> None:
        conn, _ = server.accept()
        with conn:
            while len(got) < 3000:
                chunk = conn.recv(4096)
                if not chunk:
                    break
                got.extend(chunk)

    reader = threading.Thread(target=serve)
    reader.start()
    port = serial.serial_for_url(f"socket://{host}:{port_no}", timeout=0.02, write_timeout=2.0)
    try:
        counted: list[int] = []
        for _ in range(3):
            write_all(port, bytes(range(250)) * 4, 2.0, counted.append)
        reader.join(10)
        assert bytes(got) == (bytes(range(250)) * 4) * 3 and sum(counted) == 3000
    finally:
        port.close()
        server.close()
