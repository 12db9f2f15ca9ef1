"""Test support shipped with the bus: free ports, a router process, child processes that are always stopped, and
``ModuleDriver`` to drive a module with typed events in a unit test without a router.

Used by this project's tests and usable by anyone testing their own modules against a real router.
"""

from __future__ import annotations

import fcntl
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from bbcs import keys
from bbcs.context import ModuleContext
from bbcs.errors import SlotError
from bbcs.events import Event, Input, RouteChange, Stop, Tick
from bbcs.lockstep import Member
from bbcs.module import Module
from bbcs.net import free_port, wait_tcp
from bbcs.routing import RouteAck
from bbcs.slots import Direction, SlotSpec

__all__ = ["free_port", "wait_port", "wait_until", "child_env", "stop_process", "start_router", "Processes",
           "run_turn", "ModuleDriver", "Recorder", "Input", "Tick", "RouteChange", "Stop"]

ROOT = Path(__file__).resolve().parents[1]


def wait_port(port: int, deadline_s: float = 30.0) -> None:
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


@contextmanager
def run_turn(folder: str | Path, alone: bool) -> Iterator[None]:
    """A turn to run tests (this project's conftest: one test file) among processes sharing ``folder`` (pytest-xdist
    workers): a shared turn beside other shared ones, an ``alone`` turn once no other turn is held, and no turn
    begins while an ``alone`` turn waits.

    Two ``flock``s: ``run`` (shared, or exclusive when alone) and ``gate``, which a waiting alone turn holds
    exclusively so that new shared turns queue behind it instead of starving it."""
    folder = Path(folder)
    with open(folder / "gate", "a+") as gate, open(folder / "run", "a+") as run:
        fcntl.flock(gate, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        if not alone:
            fcntl.flock(gate, fcntl.LOCK_UN)
        fcntl.flock(run, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        try:
            yield
        finally:
            fcntl.flock(run, fcntl.LOCK_UN)
            if alone:
                fcntl.flock(gate, fcntl.LOCK_UN)


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


def put_until_heard(put: Callable[[], None], heard: Callable[[], bool], what: str, deadline_s: float = 20.0) -> None:
    """``put`` again every 0.25 s until ``heard``; fail naming ``what`` at the deadline. A Zenoh session just opened
    may not yet know the router's subscribers and drop its first puts: an attack test first makes its attacker
    heard (an attack never sent would prove nothing), then a marker heard after the attack follows it (one
    session's puts stay in order)."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        put()
        again = time.monotonic() + 0.25
        while time.monotonic() < again:
            if heard():
                return
            time.sleep(0.005)
    raise AssertionError(f"timed out after {deadline_s:g} s waiting for {what}")


def wait_until(predicate: Callable[[], bool], deadline_s: float = 10.0, what: str = "condition") -> None:
    """Poll ``predicate`` until true; fail the test naming ``what`` at the deadline (no fixed sleeps)."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if predicate():
            return
        time.sleep(0.01)
    raise AssertionError(f"timed out after {deadline_s} s waiting for {what}")


def wait_alive(session: Any, robot: str, module: str, deadline_s: float = 20.0) -> None:
    """Wait until ``module`` of ``robot`` holds its liveliness token (declared once it is up); fail naming it."""
    seen = threading.Event()
    sub = session.liveliness().declare_subscriber(keys.alive_key(robot, module), lambda _s: seen.set(), history=True)
    try:
        if not seen.wait(deadline_s):
            raise AssertionError(f"{module} of {robot} never came up within {deadline_s:g} s")
    finally:
        sub.undeclare()


def start_router(processes: Processes, host: str = "127.0.0.1", connect: tuple[str, ...] = ()) -> int:
    """Start ``cromat router`` on a free port of ``host`` (linked to the routers at ``connect``); returns the port
    once it accepts connections."""
    port = free_port()
    links = [arg for endpoint in connect for arg in ("--connect", endpoint)]
    processes.start(["-m", "bbcs.router", "--listen", f"tcp/{host}:{port}", *links], stdout=subprocess.DEVNULL)
    wait_port(port)
    return port


class Recorder:
    """Stands in for an output slot's publisher in a ``ModuleDriver``: keeps every published struct, in order."""

    def __init__(self, spec: Any, key: str) -> None:
        self.spec = spec
        self.key = key
        self.values: list[Any] = []
        self.published = 0
        self.backpressure_events = 0

    def publish(self, value: Any) -> None:
        if type(value) is not self.spec.type:
            raise SlotError(f"slot {self.spec.name!r} carries {self.spec.type.__name__}, not {type(value).__name__}")
        self.values.append(value)
        self.published += 1

    def publish_raw(self, payload: bytes) -> None:
        self.values.append(self.spec.codec.decode(payload))
        self.published += 1

    def close(self) -> None:
        return None


class ModuleDriver:
    """Drive a module with typed events in a unit test, without a router or a session (like dora's MockNode).

    ``start()`` runs ``on_start``; ``feed(Input(slot, struct_or_bytes), Tick(), RouteChange({...}), Stop())``
    handles each event exactly as the module's loop does (a struct is encoded and validated as if it came off
    the wire, so an out-of-range one is rejected with its error code); ``published[slot]`` holds what each
    output slot published, ``errors`` the error codes, ``acks`` the RouteAcks. Route changes are checked against
    ``context.slot_table`` like on the bus; inputs are fed whatever their route.
    """

    def __init__(self, module_cls: type[Module], context: ModuleContext | None = None, **context_fields: Any) -> None:
        if context is None:
            context_fields.setdefault("robot", "test")
            context_fields.setdefault("module", module_cls.name)
            context = ModuleContext(**context_fields)
        self.module = module_cls(context)
        m = self.module
        self._recorders = {name: Recorder(spec, spec.key(m.robot, m.module)) for name, spec in m._outputs.items()}
        m._outputs_by_name = dict(self._recorders)
        self._acks = Recorder(SlotSpec("route", RouteAck, Direction.OUT), keys.route_ack_key(m.robot, m.module))
        m._ack_pub = self._acks
        self.started = False
        self.stopped = False

    @property
    def published(self) -> dict[str, list[Any]]:
        return {name: rec.values for name, rec in self._recorders.items()}

    @property
    def errors(self) -> list[int]:
        """Error codes published on the module's ERROR slot, in order (empty if it declares none)."""
        field = self.module._error_field
        slot = self.module.error_slot
        if slot is None or field is None:
            return []
        return [int(getattr(v, field)) for v in self._recorders[slot].values]

    @property
    def acks(self) -> list[RouteAck]:
        return list(self._acks.values)

    def start(self) -> ModuleDriver:
        self.module._declare_inputs()
        with self.module.lock:
            self.module.on_start()
        self.module._running = True
        self.started = True
        return self

    def feed(self, *events: Event) -> ModuleDriver:
        if not self.started:
            self.start()
        for event in events:
            if isinstance(event, Stop):
                self.stop()
            else:
                self.module.handle_event(event)
        return self

    def stop(self) -> None:
        if not self.stopped:
            self.stopped = True
            self.module.request_stop()
            with self.module.lock:
                self.module._call_safely("stop", self.module.on_stop)

    def __enter__(self) -> ModuleDriver:
        return self.start()

    def __exit__(self, *_: object) -> None:
        self.stop()


class CutRelay:
    """A relay in front of a TCP port on 127.0.0.1 that a test can cut and heal: ``cut()`` closes every connection
    it carries and refuses new ones until ``heal()``. It listens on a Unix socket (``unix``: reachable from another
    network namespace through the file system) or on a free TCP port of 127.0.0.1 (``tcp``, its ``port``)."""

    def __init__(self, listener: socket.socket, target_port: int) -> None:
        self.target_port = target_port
        self._listener = listener
        self.port: int | None = listener.getsockname()[1] if listener.family == socket.AF_INET else None
        self._lock = threading.Lock()
        self._open = True
        self._conns: list[socket.socket] = []
        self.accepted = 0
        """Connections relayed so far (a reconnection after a heal counts one more)."""
        threading.Thread(target=self._accept, daemon=True).start()

    @classmethod
    def unix(cls, path: Path, target_port: int) -> CutRelay:
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        listener.bind(str(path))
        listener.listen(8)
        return cls(listener, target_port)

    @classmethod
    def tcp(cls, target_port: int) -> CutRelay:
        return cls(socket.create_server(("127.0.0.1", 0)), target_port)

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self._listener.accept()
            except OSError:
                return
            with self._lock:
                if not self._open:
                    client.close()
                    continue
                upstream = socket.create_connection(("127.0.0.1", self.target_port))
                self._conns += [client, upstream]
                self.accepted += 1
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    @staticmethod
    def _pump(src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                dst.sendall(data)
        except OSError:
            pass
        for s in (src, dst):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def cut(self) -> None:
        with self._lock:
            self._open = False
            for c in self._conns:
                try:
                    c.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                c.close()
            self._conns.clear()

    def heal(self) -> None:
        with self._lock:
            self._open = True

    def close(self) -> None:
        self.cut()
        self._listener.close()


class StepGate:
    """A test's hand on a lockstep robot's barrier (docs/simulation.md): a member that answers every step at once
    while open and keeps the simulation at its step while closed, so what a test does over the wall clock (a
    MAVLink command through MAVSDK, a ground station's request) lands at the simulated moment it chose, at any
    load and speed. Closed for longer than the barrier's ``deadline_s`` it is left behind, as any member is.

    ``with gate.closed():`` holds the simulation for the block's duration."""

    NAME = "test_gate"

    def __init__(self, session: Any, robot: str, name: str = NAME) -> None:
        self._lock = threading.Lock()
        self._open = True
        self._waiting: Any = None
        self.member = Member(session, robot, name, self._on_ask)

    def _on_ask(self, ask: Any) -> None:
        with self._lock:
            if not self._open:
                self._waiting = ask
                return
        self.member.answer(ask, 0)

    def close(self) -> None:
        """Hold the simulation at the step it is at (it finishes the step under way)."""
        with self._lock:
            self._open = False

    def open(self) -> None:
        with self._lock:
            self._open = True
            ask, self._waiting = self._waiting, None
        if ask is not None:
            self.member.answer(ask, 0)

    @contextmanager
    def closed(self) -> Iterator[None]:
        self.close()
        try:
            yield
        finally:
            self.open()

    def leave(self) -> None:
        """Stop taking part (the simulation no longer waits for this gate)."""
        self.open()
        self.member.close()


@contextmanager
def running(module: Module, stop_s: float = 20.0) -> Iterator[Module]:
    """Run ``module``'s event loop on a thread of this process (on the bus its context names) for the block; then
    stop it and check that its loop ended within ``stop_s``."""
    loop = threading.Thread(target=module.run, name=f"{module.module}-loop", daemon=True)
    loop.start()
    try:
        yield module
    finally:
        module.request_stop()
        loop.join(stop_s)
    assert not loop.is_alive(), f"{module.module}'s loop did not stop within {stop_s:g} s"
