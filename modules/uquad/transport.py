"""Byte streams the flight loop selects on: ``tcp://host:port`` (a simulator's end), a serial device (pyserial)
or a recorded raw file (the seed's fake mode). Non-blocking reads; ``fileno()`` for select()."""

from __future__ import annotations

import select
import socket
import time

import serial


class Stream:
    def __init__(self, url: str, baud: int = 115200, connect_timeout_s: float = 10.0) -> None:
        self.url = url
        self._sock: socket.socket | None = None
        self._serial: serial.Serial | None = None
        self._file = None
        if url.startswith("tcp://"):
            host, _, port = url.removeprefix("tcp://").rpartition(":")
            deadline = time.monotonic() + connect_timeout_s
            while True:
                try:
                    self._sock = socket.create_connection((host, int(port)), timeout=1.0)
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.05)
            self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._sock.setblocking(False)
        elif url.startswith("file://"):
            self._file = open(url.removeprefix("file://"), "rb")  # noqa: SIM115 - closed in close()
        else:
            self._serial = serial.Serial(url, baud, timeout=0)

    @property
    def socket(self) -> socket.socket | None:
        return self._sock

    def fileno(self) -> int:
        if self._sock is not None:
            return self._sock.fileno()
        if self._serial is not None:
            return self._serial.fileno()
        return self._file.fileno()

    def read(self) -> bytes:
        """What is available now; b'' when nothing (EOFError when the far end closed)."""
        if self._sock is not None:
            try:
                data = self._sock.recv(65536)
            except (BlockingIOError, InterruptedError):
                return b""
            if not data:
                raise EOFError(f"{self.url} closed")
            return data
        if self._serial is not None:
            return self._serial.read(self._serial.in_waiting or 1)
        data = self._file.read(4096)
        if not data:
            raise EOFError(f"{self.url}: end of the recorded log")
        return data

    def close(self) -> None:
        for thing in (self._sock, self._serial, self._file):
            if thing is not None:
                thing.close()


def read_available(stream: Stream) -> tuple[bytes, EOFError | None]:
    """Everything ``stream`` has now (the flight loop handles it as one read), and the end of the stream if it came.

    Why the pair: the bytes read before the far end closed (the simulator's last frames, the tail of a recorded
    raw log, which arrives in the same reads as its end) are still frames to handle; raising at the end would lose
    them."""
    chunks: list[bytes] = []
    try:
        chunks.append(stream.read())
        while stream.fileno() in select.select([stream.fileno()], [], [], 0)[0]:
            chunks.append(stream.read())
    except EOFError as end:
        return b"".join(chunks), end
    return b"".join(chunks), None
