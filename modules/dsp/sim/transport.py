"""The simulator's end of the line: a pty pair (the PC opens the slave path) or a TCP port on 127.0.0.1.

Writes never block: with nobody reading, bytes are lost, as on a real UART. The pty endpoint keeps its own
slave descriptor open so the master never sees a hang-up between PC sessions, and it reads the line speed the
PC set on the slave so the simulator can behave like a DSP at a different baud rate (garbage both ways).
"""

from __future__ import annotations

import errno
import logging
import os
import socket
import termios
import tty
from typing import Protocol

log = logging.getLogger(__name__)

_SPEEDS = {getattr(termios, f"B{rate}"): rate for rate in (
    50, 75, 110, 134, 150, 200, 300, 600, 1200, 1800, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400,
    460800, 500000, 576000, 921600, 1000000, 1152000, 1500000, 2000000, 2500000, 3000000, 3500000, 4000000)
    if hasattr(termios, f"B{rate}")}


class Endpoint(Protocol):
    """What the simulator's loop needs from a transport."""

    description: str

    def fileno_list(self) -> list[int]: ...

    def on_readable(self, fd: int) -> bytes: ...

    def write(self, data: bytes) -> int: ...

    def line_baud(self) -> int | None: ...

    def close(self) -> None: ...


class PtyEndpoint:
    """A pseudo-terminal pair; ``path`` is the slave device the PC opens like any serial port."""

    def __init__(self, baud: int = 921_600) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line editing, all 256 byte values pass
        code = next((c for c, rate in _SPEEDS.items() if rate == baud), None)
        if code is not None:  # start at the DSP's own speed: only a PC that sets another one is "wrong"
            attrs = termios.tcgetattr(self._slave)
            attrs[4] = attrs[5] = code
            termios.tcsetattr(self._slave, termios.TCSANOW, attrs)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self.description = f"pty {self.path}"

    def fileno_list(self) -> list[int]:
        return [self._master]

    def on_readable(self, fd: int) -> bytes:
        try:
            return os.read(self._master, 65536)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:  # no reader on the other side
                return b""
            raise

    def write(self, data: bytes) -> int:
        """Bytes written; the rest is lost when the PC is not draining the line."""
        try:
            return os.write(self._master, data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError as exc:
            if exc.errno == errno.EIO:
                return 0
            raise

    def line_baud(self) -> int | None:
        """The speed the PC configured on the slave (None when it is not a standard rate)."""
        try:
            return _SPEEDS.get(termios.tcgetattr(self._slave)[4])
        except termios.error:
            return None

    def close(self) -> None:
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass


class TcpEndpoint:
    """Listens on ``host:port`` (127.0.0.1 by default; port 0 picks a free one); one PC client at a time.

    A second client is refused (closed at once, counted in ``refused``): a serial line has one PC on it, and a
    stray connection must not knock the DSP process off its link."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0) -> None:
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind((host, port))
        self._listener.listen(1)
        self._listener.setblocking(False)
        self.host, self.port = self._listener.getsockname()[:2]
        self._client: socket.socket | None = None
        self.refused = 0
        self.connections = 0
        """PCs that took the line so far (a lockstep simulator counts the line's bytes per connection)."""
        self.description = f"tcp {self.host}:{self.port}"

    def fileno_list(self) -> list[int]:
        # the client first: a PC that hung up and reconnects at once is seen gone before its new connection
        fds = [self._client.fileno()] if self._client is not None else []
        fds.append(self._listener.fileno())
        return fds

    def _client_gone(self) -> bool:
        """Whether the PC on the line has hung up (its end closed or reset) without our having read it yet."""
        assert self._client is not None
        try:
            return self._client.recv(1, socket.MSG_PEEK) == b""
        except (BlockingIOError, InterruptedError):
            return False
        except OSError:
            return True

    def on_readable(self, fd: int) -> bytes:
        if fd == self._listener.fileno():
            try:
                conn, _ = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return b""
            if self._client is not None and self._client_gone():  # a restarted PC: the old one hung up
                self._client.close()
                self._client = None
            if self._client is not None:  # the line is taken: refuse, keep the PC that has it
                conn.close()
                self.refused += 1
                log.warning("refused a second client on %s: the line already has one", self.description)
                return b""
            conn.setblocking(False)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._client = conn
            self.connections += 1
            return b""
        if self._client is None:
            return b""
        try:
            data = self._client.recv(65536)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            data = b""
        if not data:
            self._client.close()
            self._client = None
        return data

    def write(self, data: bytes) -> int:
        if self._client is None:
            return 0
        try:
            return self._client.send(data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError:
            self._client.close()
            self._client = None
            return 0

    def line_baud(self) -> int | None:
        return None  # a socket has no line speed

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        self._listener.close()
