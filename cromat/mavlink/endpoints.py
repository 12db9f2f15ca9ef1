"""Where MAVLink bytes come and go: UDP to a ground station, a TCP server, a serial port (a telemetry radio).

Each endpoint reads on a thread of its own and hands ``(peer, bytes)`` to one callback; ``send`` writes a frame to
every peer it has. Nothing listens beyond loopback unless the address says so (``--bind``).
"""

from __future__ import annotations

import ipaddress
import logging
import socket
import threading
from collections.abc import Callable
from typing import Protocol

log = logging.getLogger("cromat.mavlink")

Received = Callable[[str, bytes], None]
"""Called with a peer's name (``udp:HOST:PORT``, ``tcp:HOST:PORT``, ``serial:URL``) and the bytes it sent."""

QGC_PORT = 14550
"""QGroundControl listens for vehicles on UDP 14550 by default."""


class EndpointError(ValueError):
    """An endpoint that cannot be opened (bad address, port taken, no such device), with the reason."""


class Endpoint(Protocol):
    name: str

    def start(self, received: Received) -> None: ...
    def send(self, frame: bytes) -> None: ...
    def close(self) -> None: ...


def parse_host_port(text: str, what: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise EndpointError(f"{what} {text!r}: expected HOST:PORT (e.g. 127.0.0.1:{QGC_PORT})")
    return host, int(port)


def is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


class UdpTarget:
    """Sends to one ground station (QGroundControl's 14550, or ``--udp HOST:PORT``) from a socket bound on
    ``bind``; whoever answers from another address is answered too (a MAVSDK or pymavlink script)."""

    def __init__(self, host: str, port: int, bind: str = "127.0.0.1") -> None:
        if not is_loopback(host) and is_loopback(bind):
            raise EndpointError(f"udp {host}:{port}: the gateway binds on loopback ({bind}); give --bind 0.0.0.0 "
                                "(or this machine's address) to reach another machine")
        self.name = f"udp:{host}:{port}"
        self.target = (socket.gethostbyname(host), port)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((bind, 0))
        except OSError as exc:
            self.sock.close()
            raise EndpointError(f"{self.name}: cannot bind on {bind}: {exc}") from None
        self.peers: set[tuple[str, int]] = {self.target}
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._closed = False

    def start(self, received: Received) -> None:
        def run() -> None:
            while not self._closed:
                try:
                    data, addr = self.sock.recvfrom(65536)
                except OSError:
                    return
                if self._closed or not addr:
                    return
                with self._lock:
                    self.peers.add(addr)
                received(f"udp:{addr[0]}:{addr[1]}", data)

        self._thread = threading.Thread(target=run, name=f"mavlink.{self.name}", daemon=True)
        self._thread.start()

    def send(self, frame: bytes) -> None:
        with self._lock:
            peers = list(self.peers)
        for addr in peers:
            try:
                self.sock.sendto(frame, addr)
            except OSError:  # nobody listening yet (ICMP port unreachable): keep sending, as a vehicle does
                pass

    def close(self) -> None:
        self._closed = True
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()
        if self._thread is not None:
            self._thread.join(2.0)


class TcpServer:
    """A TCP server (``--tcp PORT``): every connected ground station gets every frame."""

    def __init__(self, port: int, bind: str = "127.0.0.1") -> None:
        self.server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.server.bind((bind, port))
        except OSError as exc:
            self.server.close()
            raise EndpointError(f"tcp {bind}:{port}: cannot listen: {exc}") from None
        self.server.listen(8)
        self.port = self.server.getsockname()[1]
        self.name = f"tcp:{bind}:{self.port}"
        self.clients: dict[socket.socket, str] = {}
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        self._closed = False

    def start(self, received: Received) -> None:
        def serve(conn: socket.socket, peer: str) -> None:
            while not self._closed:
                try:
                    data = conn.recv(65536)
                except OSError:
                    data = b""
                if not data:
                    break
                received(peer, data)
            with self._lock:
                self.clients.pop(conn, None)
            conn.close()

        def accept() -> None:
            while not self._closed:
                try:
                    conn, addr = self.server.accept()
                except OSError:
                    return
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                peer = f"tcp:{addr[0]}:{addr[1]}"
                with self._lock:
                    self.clients[conn] = peer
                t = threading.Thread(target=serve, args=(conn, peer), name=f"mavlink.{peer}", daemon=True)
                self._threads.append(t)
                t.start()

        t = threading.Thread(target=accept, name=f"mavlink.{self.name}", daemon=True)
        self._threads.append(t)
        t.start()

    def send(self, frame: bytes) -> None:
        with self._lock:
            conns = list(self.clients)
        for conn in conns:
            try:
                conn.sendall(frame)
            except OSError:
                with self._lock:
                    self.clients.pop(conn, None)

    def close(self) -> None:
        self._closed = True
        for s in [self.server, *list(self.clients)]:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()
        for t in self._threads:
            t.join(2.0)


class SerialPort:
    """A telemetry radio: a device (``/dev/ttyUSB0``, ``/dev/ttyUSB0:57600``) or any pyserial URL
    (``socket://HOST:PORT``, ``rfc2217://...``, ``loop://``)."""

    def __init__(self, url: str, baud: int = 57600) -> None:
        import serial

        device, sep, rate = url.rpartition(":")
        if sep and rate.isdigit() and "://" not in url:
            url, baud = device, int(rate)
        self.name = f"serial:{url}"
        try:
            self.port = serial.serial_for_url(url, baudrate=baud, timeout=0.2)
        except (serial.SerialException, ValueError) as exc:
            raise EndpointError(f"serial {url}: cannot open: {exc}") from None
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._closed = False

    def start(self, received: Received) -> None:
        def run() -> None:
            while not self._closed:
                try:
                    data = self.port.read(4096)
                except Exception:  # noqa: BLE001 - a device gone: stop reading, say so once
                    if not self._closed:
                        log.warning("%s: read failed; no more frames from it", self.name)
                    return
                if data:
                    received(self.name, bytes(data))

        self._thread = threading.Thread(target=run, name=f"mavlink.{self.name}", daemon=True)
        self._thread.start()

    def send(self, frame: bytes) -> None:
        with self._lock:
            try:
                self.port.write(frame)
            except Exception:  # noqa: BLE001 - a radio out of range must not stop the other endpoints
                pass

    def close(self) -> None:
        self._closed = True
        if self._thread is not None:
            self._thread.join(2.0)
        self.port.close()
