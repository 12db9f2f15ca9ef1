"""Test support shipped with the bus: free ports, a router process, child processes that are always stopped.

Used by this project's tests and usable by anyone testing their own modules against a real router.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from bbcs.net import free_port, wait_tcp

__all__ = ["free_port", "wait_port", "wait_until", "child_env", "stop_process", "start_router", "Processes"]

ROOT = Path(__file__).resolve().parents[1]


def wait_port(port: int, deadline_s: float = 10.0) -> None:
    if not wait_tcp("127.0.0.1", port, deadline_s):
        raise TimeoutError(f"nothing listens on 127.0.0.1:{port} after {deadline_s} s")


def child_env(**extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.setdefault("CROMAT_LOG", "WARNING")
    env.update(extra)
    return env


def stop_process(proc: subprocess.Popen, grace_s: float = 10.0) -> int | None:
    """SIGTERM, then SIGKILL after ``grace_s``; returns the exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    return proc.returncode


class Processes:
    """Starts child processes and stops every one of them at teardown."""

    def __init__(self) -> None:
        self.procs: list[subprocess.Popen] = []

    def start(self, args: list[str], **popen: object) -> subprocess.Popen:
        popen.setdefault("env", child_env())
        popen.setdefault("cwd", str(ROOT))
        proc = subprocess.Popen([sys.executable, *args], **popen)  # type: ignore[call-overload]
        self.procs.append(proc)
        return proc

    def stop_all(self) -> None:
        for proc in reversed(self.procs):
            stop_process(proc)
            for stream in (proc.stdout, proc.stderr, proc.stdin):
                if stream is not None:
                    stream.close()


def wait_until(predicate: Callable[[], bool], deadline_s: float = 10.0, what: str = "condition") -> None:
    """Poll ``predicate`` until true; fail the test naming ``what`` at the deadline (no fixed sleeps)."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if predicate():
            return
        time.sleep(0.01)
    raise AssertionError(f"timed out after {deadline_s} s waiting for {what}")


def start_router(processes: Processes, host: str = "127.0.0.1") -> int:
    """Start ``cromat router`` on a free port of ``host``; returns the port once it accepts connections."""
    port = free_port()
    processes.start(["-m", "bbcs.router", "--listen", f"tcp/{host}:{port}"], stdout=subprocess.DEVNULL)
    wait_port(port)
    return port
