"""A reader of the uQuad simulator's truth stream (``--truth``: one JSON line of the true state per frame).

For tests, benchmarks and anyone watching a simulated flight: the lines arrive on a thread of their own and are
kept in order (``lines``), each a dict as the simulator wrote it (in lockstep with ``t`` and ``stamp``,
docs/uquad.md §1.1).
"""

from __future__ import annotations

import json
import socket
import threading


class TruthStream:
    """Connects to the truth port on 127.0.0.1 and keeps every line read; ``close`` ends it."""

    def __init__(self, port: int, host: str = "127.0.0.1") -> None:
        self.sock = socket.create_connection((host, port))
        self.lines: list[dict] = []
        self.thread = threading.Thread(target=self._read, name="uquad-truth", daemon=True)
        self.thread.start()

    def _read(self) -> None:
        buf = b""
        while True:
            try:
                data = self.sock.recv(65536)
            except OSError:
                return
            if not data:
                return
            buf += data
            *done, buf = buf.split(b"\n")
            self.lines += [json.loads(line) for line in done if line]

    @property
    def last(self) -> dict:
        """The newest line (IndexError before the first)."""
        return self.lines[-1]

    def close(self) -> None:
        self.sock.close()
