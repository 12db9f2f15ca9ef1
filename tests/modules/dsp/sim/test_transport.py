"""The simulator's line ends: a pty the PC opens like a serial port, and a TCP port on 127.0.0.1."""

from __future__ import annotations

import select
import socket

import serial

from modules.dsp.sim.transport import PtyEndpoint, TcpEndpoint


def read_some(ep, fd: int, timeout: float = 2.0) -> bytes:
    ready, _, _ = select.select([fd], [], [], timeout)
    return ep.on_readable(fd) if ready else b""


def test_pty_carries_every_byte_and_reports_the_pc_baud() -> None:
    ep = PtyEndpoint(baud=921_600)
    try:
        assert ep.line_baud() == 921_600  # starts at the DSP's own speed
        with serial.Serial(ep.path, 115_200, timeout=1.0) as port:
            assert ep.line_baud() == 115_200
            port.write(bytes(range(256)))
            got = b""
            while len(got) < 256:
                chunk = read_some(ep, ep.fileno_list()[0])
                assert chunk
                got += chunk
            assert got == bytes(range(256))
            assert ep.write(bytes(range(255, -1, -1))) == 256
            assert port.read(256) == bytes(range(255, -1, -1))
    finally:
        ep.close()


def test_pty_write_never_blocks_without_a_reader() -> None:
    ep = PtyEndpoint()
    try:
        written = sum(ep.write(bytes(1024)) for _ in range(2000))  # 2 MB into a line nobody drains
        assert written < 2_000_000
    finally:
        ep.close()


def test_tcp_one_client_at_a_time() -> None:
    ep = TcpEndpoint("127.0.0.1", 0)
    try:
        assert ep.port > 0 and ep.line_baud() is None
        assert ep.write(b"nobody") == 0
        listener = ep.fileno_list()[0]
        first = socket.create_connection(("127.0.0.1", ep.port))
        read_some(ep, listener)
        assert len(ep.fileno_list()) == 2
        first.sendall(b"hello")
        assert read_some(ep, client_fd(ep, listener)) == b"hello"
        second = socket.create_connection(("127.0.0.1", ep.port))
        read_some(ep, listener)  # a second PC is refused (issue 12): the first keeps the line
        assert second.recv(10) == b"" and ep.refused == 1
        assert ep.write(b"to-first") == 8
        assert first.recv(20) == b"to-first"
        second.close()
        first.close()
        assert read_some(ep, client_fd(ep, listener)) == b""
        assert len(ep.fileno_list()) == 1
    finally:
        ep.close()


def client_fd(ep: TcpEndpoint, listener: int) -> int:
    return next(fd for fd in ep.fileno_list() if fd != listener)


def test_tcp_a_pc_that_hung_up_and_reconnects_gets_the_line() -> None:
    """A restarted DSP process: its old connection closed, its new one arrives before the old EOF was read."""
    ep = TcpEndpoint("127.0.0.1", 0)
    try:
        listener = ep.fileno_list()[0]
        old = socket.create_connection(("127.0.0.1", ep.port))
        read_some(ep, listener)
        old.close()
        new = socket.create_connection(("127.0.0.1", ep.port))
        read_some(ep, listener)  # the listener is read before the old client's EOF
        assert ep.refused == 0
        new.sendall(b"again")
        assert read_some(ep, client_fd(ep, listener)) == b"again"
        assert ep.write(b"ok") == 2 and new.recv(10) == b"ok"
        new.close()
    finally:
        ep.close()
