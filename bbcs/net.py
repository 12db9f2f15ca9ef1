"""Loopback port helpers shared by the manager (placeholders, readiness) and tests: one copy of each."""

from __future__ import annotations

import random
import socket
import time
from collections.abc import Callable
from pathlib import Path

LISTEN_PORTS = range(20000, 32768)
"""Where :func:`free_port` looks first: below Linux's default ephemeral range (32768-60999), so a port handed out
here is never taken meanwhile as the local end of some outgoing connection, and a readiness probe to it can never
connect to itself (TCP's simultaneous open, which happens when the probe's own local port is the port probed)."""


def _ephemeral() -> range:
    try:
        low, high = (int(v) for v in Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split())
    except (OSError, ValueError):
        return range(32768, 61000)
    return range(low, high + 1)


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on ``host`` right now, outside the ephemeral range where one can be found (see
    ``LISTEN_PORTS``); another listener may still take it before you bind."""
    ephemeral = _ephemeral()
    for _ in range(50):
        port = random.choice(LISTEN_PORTS)
        if port in ephemeral:
            continue
        with socket.socket() as s:
            try:
                s.bind((host, port))
            except OSError:
                continue
            return port
    with socket.socket() as s:  # the range is crowded (or is all ephemeral here): let the OS pick
        s.bind((host, 0))
        return s.getsockname()[1]


def wait_tcp(host: str, port: int, timeout_s: float, alive: Callable[[], bool] = lambda: True) -> bool:
    """True once something accepts TCP connections on host:port (False at the deadline or if ``alive`` fails)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and alive():
        try:
            with socket.create_connection((host, port), timeout=0.2):
                return True
        except OSError:
            time.sleep(0.02)
    return False
