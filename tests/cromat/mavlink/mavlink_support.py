"""What the gateway's system tests share: ``cromat mavlink`` as a process, MAVSDK and pymavlink clients.

The clients are independent of the gateway's code: MAVSDK (its wheel's C++ library, driven through its asyncio API)
and pymavlink's ``mavutil`` connections; neither imports ``cromat.mavlink``.
"""

from __future__ import annotations

import asyncio
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, TypeVar

from bbcs.testing import child_env, free_port, wait_until

ROOT = Path(__file__).resolve().parents[3]
T = TypeVar("T")


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class GatewayProcess:
    """``python -m cromat mavlink ARGS`` with every output line kept; stopped (SIGTERM, then SIGKILL) by close()."""

    def __init__(self, *args: str) -> None:
        self.lines: list[str] = []
        self.proc = subprocess.Popen([sys.executable, "-m", "cromat", "mavlink", *args], cwd=str(ROOT),
                                     env=child_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_line(self, text: str, timeout_s: float = 30.0) -> str:
        try:
            wait_until(lambda: any(text in x for x in self.lines) or self.proc.poll() is not None, timeout_s, text)
        except AssertionError as exc:
            raise AssertionError(f"{exc}; gateway output:\n" + "\n".join(self.lines[-30:])) from None
        found = next((x for x in self.lines if text in x), None)
        assert found is not None, f"the gateway exited ({self.proc.poll()}):\n" + "\n".join(self.lines[-30:])
        return found

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)


def gateway(router_port: int, *extra: str) -> tuple[GatewayProcess, int, int]:
    """A gateway on the robot router at ``router_port``: UDP to a MAVSDK port, a TCP server for pymavlink.
    Returns (process, the UDP port MAVSDK listens on, the TCP port)."""
    udp, tcp = free_udp_port(), free_port()
    gw = GatewayProcess("--connect", f"tcp/127.0.0.1:{router_port}", "--udp", f"127.0.0.1:{udp}",
                        "--tcp", str(tcp), *extra)
    gw.wait_line("serving on", 30)
    return gw, udp, tcp


def run_async(coro_fn: Callable[[], Awaitable[T]], timeout_s: float) -> T:
    """Run one MAVSDK session (a coroutine) to its end within ``timeout_s``."""
    async def bounded() -> T:
        return await asyncio.wait_for(coro_fn(), timeout_s)

    return asyncio.run(bounded())


async def first(gen: Any, pred: Callable[[Any], bool] = lambda _: True, timeout_s: float = 20.0) -> Any:
    """The first item of a MAVSDK subscription that ``pred`` accepts."""
    async def scan() -> Any:
        async for item in gen:
            if pred(item):
                return item
        raise AssertionError("the subscription ended")

    return await asyncio.wait_for(scan(), timeout_s)


class Mav:
    """A pymavlink ground station (``mavutil``), over TCP to the gateway; ``messages`` keeps what it received."""

    def __init__(self, tcp_port: int, *, sysid: int = 250, key: bytes | None = None,
                 heartbeats: bool = False) -> None:
        """``heartbeats``: send a ground station's HEARTBEAT every second, as QGroundControl does, until
        :meth:`quiet` or :meth:`close` (the gateway holds the robots' GRI link only while one is heard)."""
        os.environ.setdefault("MAVLINK20", "1")
        from pymavlink import mavutil

        self.conn = mavutil.mavlink_connection(f"tcp:127.0.0.1:{tcp_port}", source_system=sysid,
                                               source_component=190, dialect="common", autoreconnect=False)
        if key is not None:
            self.conn.setup_signing(key, sign_outgoing=True)
        self.mav = self.conn.mav
        self.messages: list[Any] = []
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()
        self._beating = threading.Event()
        self._beat_thread: threading.Thread | None = None
        if heartbeats:
            self._beating.set()
            self._beat_thread = threading.Thread(target=self._beat, daemon=True)
            self._beat_thread.start()

    def _beat(self) -> None:
        from pymavlink import mavutil

        m = mavutil.mavlink
        while self._beating.is_set() and not self._stop.is_set():
            try:
                self.mav.heartbeat_send(m.MAV_TYPE_GCS, m.MAV_AUTOPILOT_INVALID, 0, 0, m.MAV_STATE_ACTIVE)
            except OSError:
                return
            self._stop.wait(1.0)

    def quiet(self) -> None:
        """Stop sending heartbeats (the ground station goes quiet; its connection stays open)."""
        self._beating.clear()
        if self._beat_thread is not None:
            self._beat_thread.join(3.0)

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                m = self.conn.recv_match(blocking=True, timeout=0.1)
            except OSError:
                return
            if m is not None and m.get_type() != "BAD_DATA":
                with self._lock:
                    self.messages.append(m)

    def mark(self) -> int:
        with self._lock:
            return len(self.messages)

    def since(self, mark: int, kind: str | None = None, sysid: int | None = None) -> list[Any]:
        with self._lock:
            got = self.messages[mark:]
        return [m for m in got if (kind is None or m.get_type() == kind)
                and (sysid is None or m.get_srcSystem() == sysid)]

    def wait(self, mark: int, kind: str, pred: Callable[[Any], bool] = lambda _: True, timeout_s: float = 10.0,
             sysid: int | None = None) -> Any:
        found: list[Any] = []

        def seen() -> bool:
            found[:] = [m for m in self.since(mark, kind, sysid) if pred(m)]
            return bool(found)

        wait_until(seen, timeout_s, f"{kind} from the gateway")
        return found[0]

    def close(self) -> None:
        self._stop.set()
        self.quiet()
        self._thread.join(2.0)
        self.conn.close()


def settle(seconds: float) -> None:
    time.sleep(seconds)
