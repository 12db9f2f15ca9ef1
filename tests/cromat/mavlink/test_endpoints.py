"""The gateway's endpoints on real transports (UDP and TCP on 127.0.0.1, a pty for the radio) and its command line's
refusals, which stop before anything starts."""

from __future__ import annotations

import os
import pty
import socket
import threading
import tty
from pathlib import Path

import pytest

from bbcs.testing import free_port, wait_until
from cromat.mavlink import cli
from cromat.mavlink.endpoints import EndpointError, SerialPort, TcpServer, UdpTarget, parse_host_port


class Inbox:
    def __init__(self) -> None:
        self.got: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()

    def __call__(self, peer: str, data: bytes) -> None:
        with self.lock:
            self.got.append((peer, data))

    def data(self) -> bytes:
        with self.lock:
            return b"".join(d for _, d in self.got)


def test_udp_sends_to_the_ground_station_and_answers_whoever_writes() -> None:
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(5.0)
    script = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    script.bind(("127.0.0.1", 0))
    script.settimeout(5.0)
    ep, inbox = UdpTarget("127.0.0.1", gcs.getsockname()[1]), Inbox()
    try:
        ep.start(inbox)
        ep.send(b"frame1")
        data, addr = gcs.recvfrom(100)
        assert data == b"frame1"
        script.sendto(b"hello", addr)  # a second station (a script) writes: it is answered too
        wait_until(lambda: inbox.data() == b"hello", 5, "the script's datagram")
        assert inbox.got[0][0] == f"udp:127.0.0.1:{script.getsockname()[1]}"
        ep.send(b"frame2")
        assert gcs.recvfrom(100)[0] == b"frame2" and script.recvfrom(100)[0] == b"frame2"
    finally:
        ep.close()
        gcs.close()
        script.close()


def test_tcp_server_serves_every_client() -> None:
    ep, inbox = TcpServer(0), Inbox()
    a = b = None
    try:
        ep.start(inbox)
        a = socket.create_connection(("127.0.0.1", ep.port), 5)
        b = socket.create_connection(("127.0.0.1", ep.port), 5)
        wait_until(lambda: len(ep.clients) == 2, 5, "two clients")
        ep.send(b"frame")
        assert a.recv(100) == b"frame" and b.recv(100) == b"frame"
        a.sendall(b"cmd")
        wait_until(lambda: inbox.data() == b"cmd", 5, "the client's bytes")
    finally:
        for s in (a, b):
            if s is not None:
                s.close()
        ep.close()


def test_serial_radio_on_a_pty() -> None:
    master, slave = pty.openpty()
    tty.setraw(slave)
    ep, inbox = SerialPort(f"{os.ttyname(slave)}:57600"), Inbox()
    try:
        ep.start(inbox)
        os.write(master, b"\xfd radio bytes")
        wait_until(lambda: inbox.data() == b"\xfd radio bytes", 5, "the radio's bytes")
        ep.send(b"frame")
        assert os.read(master, 100) == b"frame"
    finally:
        ep.close()
        os.close(master)
        os.close(slave)


def test_refusals_name_what_is_wrong() -> None:
    with pytest.raises(EndpointError, match="--bind 0.0.0.0"):
        UdpTarget("192.0.2.1", 14550)  # another machine while bound to loopback
    with pytest.raises(EndpointError, match="HOST:PORT"):
        parse_host_port("14550", "--udp")
    with pytest.raises(EndpointError, match="cannot open"):
        SerialPort("/dev/no-such-radio")
    busy = TcpServer(0)
    try:
        with pytest.raises(EndpointError, match="cannot listen"):
            TcpServer(busy.port)
    finally:
        busy.close()


def test_command_line_errors_stop_before_anything_starts(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "robot.toml"
    bad.write_text('[robot]\nname = "uav1"\nkind = "uav"\nconf = "missing.conf"\n')
    assert cli.main(["--manifest", str(bad), "--tcp", str(free_port())]) == 2
    err = capsys.readouterr().err
    assert "robot.toml" in err and "missing.conf" in err
    assert cli.main(["--robot", "uav1=300"]) == 2
    assert "1..255" in capsys.readouterr().err
    assert cli.main(["--udp", "nohostport"]) == 2
    assert "HOST:PORT" in capsys.readouterr().err
    key = tmp_path / "empty.key"
    key.write_text("")
    assert cli.main(["--signing-key", str(key)]) == 2
    assert "empty" in capsys.readouterr().err
    # nothing listens on this port: the router is unreachable, the endpoints opened are closed again
    port = free_port()
    assert cli.main(["--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout", "1", "--tcp", str(port)]) == 3
    TcpServer(port).close()  # the port is free again
