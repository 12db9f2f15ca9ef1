"""The Module Manager at run time: router first, then simulators and modules, supervised; routes, modes,
tasks, robot state and the MRI on the bus.

Threads: the *main* thread runs :meth:`Manager.run` — it spawns (the parent-death signal is tied to the forking
thread), reaps children, ticks the supervisors. Zenoh callbacks update state under one lock; MRI queries are
served by one thread of their own, so a request that waits for a module's acknowledgement never blocks the
callbacks that bring it.
"""

from __future__ import annotations

import os
import re
import select
import shutil
import signal
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec
import zenoh

from bbcs import (
    EXIT_CONFIG,
    Direction,
    Heartbeat,
    Kind,
    Publisher,
    RouteAck,
    Safety,
    SessionConfig,
    SlotSpec,
    keys,
    open_session,
    router_audit,
    wire,
)
from bbcs.context import CONTEXT_ENV, ModuleContext, encode_context
from bbcs.contracts import mri
from bbcs.contracts.error_codes import RouterErrorCode
from bbcs.contracts.errors import ErrorReport
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.net import free_port, wait_tcp
from module_manager import bus_links, direct_links, lockstep, route_audit, secure, unique_name
from module_manager.manifest import MANAGER_MODULE, Manifest, ModuleInfo, cpu_list
from module_manager.mri_service import MriService
from module_manager.params import ParamDesk
from module_manager.process import Child, Priority, stop_children
from module_manager.route_control import RouteControl
from module_manager.standby import context_line, standby_argv
from module_manager.status_lines import print_line
from module_manager.supervision import Kill, Phase, Spawn, Supervisor, launch_gave_up, startable
from module_manager.task_data import kept
from module_manager.tasks import TaskBook

ROOT = Path(__file__).resolve().parents[1]
MAX_ERRORS = 32
MESH_POLL_S = 0.05
"""How often the launch looks at the peer modules' links while it waits for them (``direct_links``)."""
MESH_WAIT_S = 10.0
"""How long a peer module waits for its direct links; then it counts as up all the same, the
launch naming what is still apart (a module that never comes up would be worse; links form in well under a second
here). Less than a module's default ``start_timeout_s``, which would otherwise kill it first."""
_decode_error = msgspec.msgpack.Decoder(ErrorReport).decode
_PLACEHOLDER = re.compile(r"\{(port:[A-Za-z0-9_]+|python|manifest_dir|conf|robot)\}")


def config_refusals(modules: dict[str, tuple[Phase, int | None]]) -> list[str]:
    """The modules that refused their configuration (failed with ``EXIT_CONFIG``, never restarted): during a
    launch any one of them stops the whole robot rather than leaving it up without that module."""
    return [name for name, (phase, last_exit) in modules.items() if phase is Phase.FAILED and last_exit == EXIT_CONFIG]


def _last_line(path: Path) -> str:
    """The last non-empty line of a child's log (what a module says when it refuses its configuration)."""
    try:
        lines = [x.strip() for x in path.read_text(errors="replace").splitlines()[-20:] if x.strip()]
    except OSError:
        return ""
    return lines[-1][-300:] if lines else ""


DUE_SLACK_S = 1e-6
"""A robot state due at simulated time T is due at T minus float rounding: a simulator's time is a sum of its
physics steps (ten 0.02 s steps make 0.19999999999999998 s), and without this slack the state due at 0.2 s
waited for the next barrier step, so on a UAV in lockstep only 58 % of the 0.2 s steps carried one."""


def state_due(now: float, due_at: float) -> bool:
    """Whether the robot state due at ``due_at`` is due at ``now`` (both on the robot's clock)."""
    return now + DUE_SLACK_S >= due_at


class LaunchError(RuntimeError):
    """Something the manager needs before modules can start failed (router, a simulator's readiness)."""


class Expander:
    """Fills ``{port:NAME}`` (a free 127.0.0.1 port per name), ``{python}``, ``{manifest_dir}``, ``{conf}``,
    ``{robot}`` in commands, parameters and endpoints."""

    def __init__(self, manifest: Manifest) -> None:
        self.ports: dict[str, int] = {}
        self.fixed = {"python": sys.executable, "manifest_dir": str(manifest.dir), "conf": str(manifest.conf),
                      "robot": manifest.robot}

    def __call__(self, text: str) -> str:
        def sub(m: re.Match[str]) -> str:
            name = m.group(1)
            if name.startswith("port:"):
                port = self.ports.get(name[5:])
                if port is None:
                    port = self.ports[name[5:]] = free_port()
                return str(port)
            return self.fixed[name]
        return _PLACEHOLDER.sub(sub, text)


class _Module:
    """Run-time record of one module: its supervisor, process, routes, last ack/error."""

    def __init__(self, info: ModuleInfo, sup: Supervisor) -> None:
        self.info = info
        self.sup = sup
        self.child: Child | None = None
        self.run_count = 0
        self.routes = dict(info.routes)
        self.control: Publisher[Any] | None = None
        self.last_ack: RouteAck | None = None
        self.last_error: int | None = None
        self.kill_deadline: float | None = None
        self.shown = ""
        self.standby: Child | None = None
        """A warm process that becomes this module at its next restart (policy ``standby``: standby.py)."""
        self.standby_failures = 0
        self.warm_starts = 0
        self.links_since: float | None = None
        """When this run started waiting only for its direct links (``links = "peers"``)."""
        self.links_polled = 0.0


def _cpus(cpus: list[int] | None) -> frozenset[int] | None:
    """A manifest ``cpus`` list as the affinity a child gets (None: the manager's own)."""
    return frozenset(cpus) if cpus else None


FLOOD_LINE = "cromat router: flood: "
"""How the router's log names a flood it cut (bbcs/router_floods.py)."""
FLOOD_REPORT_S = 10.0


def _priority(spec: Any, lockstep_on: bool = False) -> Priority | None:
    """A manifest entry's ``nice``/``realtime`` as the priority a child gets (None: the manager's own). In a lockstep
    launch a raised priority (a negative nice, real time) is left out: the barrier makes the flight independent of
    the machine's load, so it would only take the processors from everything else on the machine (a uQuad at
    ``--speed max`` stepping flat out at nice -10; docs/simulation.md)."""
    priority = Priority(spec.nice, getattr(spec, "realtime", None))  # the router's ``[bus]`` has no real time
    if lockstep_on and _raised(priority):
        priority = Priority(spec.nice if spec.nice is not None and spec.nice >= 0 else None)
    return priority if priority else None


def _raised(p: Any) -> bool:
    """A priority (or a manifest entry) asking for more than the default: a negative nice or real time."""
    return (p.nice is not None and p.nice < 0) or getattr(p, "realtime", None) is not None


def raised_priorities(specs: dict[str, Any]) -> list[str]:
    """The manifest entries asking for a raised priority (a negative nice or real time), by name."""
    return sorted(n for n, spec in specs.items() if _raised(spec))


def _on(cpus: list[int] | None) -> str:
    return f" on cpus {cpu_list(set(cpus))}" if cpus else ""


def tcp_endpoint(endpoint: str) -> tuple[str, int] | None:
    """``tcp/host:port`` → (host to connect to, port); None for other protocols."""
    proto, _, addr = endpoint.partition("/")
    if proto not in ("tcp", "tls") or ":" not in addr:
        return None
    host, _, port = addr.rpartition(":")
    host = host.strip("[]")
    if host in ("0.0.0.0", "", "::"):
        host = "127.0.0.1"
    return host, int(port.split("#")[0])


class Manager(RouteControl, MriService):
    """Launch and supervise one robot from a checked manifest."""

    def __init__(self, manifest: Manifest, *, listen: list[str] | None = None, log_dir: Path | None = None,
                 out: Callable[[str], None] | None = None, clock: Callable[[], float] = time.monotonic,
                 speed: float | str | None = None) -> None:
        self.m = manifest
        self.expand = Expander(manifest)
        self.listen = [self.expand(e) for e in (listen or manifest.raw.bus.listen)]
        self.log_dir = log_dir
        self.out = out or print_line
        self.clock = clock
        self.lock = threading.RLock()
        self.changed = threading.Condition(self.lock)
        self.stop_event = threading.Event()
        self.modules = {name: _Module(info, Supervisor(info.policy, needs_ack=bool(info.inputs),
                                                           needs_links=bus_links.links(manifest) == "peers"))
                        for name, info in manifest.modules.items()}
        self.mode_fields = {n: frozenset(m.type.__struct_fields__) for n, m in manifest.modes.items()}
        """Mode slot → its struct's fields: the inputs whose data a task's mode can carry (task_data.py)."""
        self.mode_streams = {n: self.mode_fields[n] & manifest.modules[m.module].streams
                             for n, m in manifest.modes.items() if m.module in manifest.modules}
        """Mode slot → its fields that carry stream data: delivered once, never kept (task_data.kept)."""
        self.carried_from: dict[str, dict[str, int]] = {}
        """Mode slot → the fields a task's start carried in it → the slot number each datum came from (set at every
        task start; a route swapped back to that number sends the mode again while its value still carries the
        datum: MriService._resend_carried)."""
        self.mode_data = {n: self.mode_fields[n] & set(manifest.modules[m.module].inputs)
                          for n, m in manifest.modes.items() if m.module in manifest.modules}
        """Mode slot → its fields that can carry a task's datum (named after an input of its module)."""
        self.tasks = TaskBook(manifest.tasks, frozenset(n for n, m in manifest.modes.items() if not m.restore),
                              self.mode_streams, self.mode_data)
        self.task_uses = task_modules(manifest)
        self.task_lost_with = {name: used - set(manifest.tasks[name].survives) for name, used in self.task_uses.items()}
        """Manifest task → the modules whose exit ends it as failed (its effect lost with them)."""
        self.modes: dict[str, dict[str, Any] | None] = {
            name: (msgspec.to_builtins(m.initial) if m.initial is not None else None)
            for name, m in manifest.modes.items()}
        self.telemetry: RobotTelemetry | None = None
        self.home: GeoPoint | None = None
        """The take-off point (RobotState.home): the robot's record, so a RAL restarted in flight still has it."""
        self._mesh_refusals: set[str] = set()
        self._floods_said: dict[str, float] = {}
        """Identity and key of a flood the router cut → when the error list last got it (``_router_flood``)."""
        self._mode_acks: dict[str, mri.ModeAck | None] = {}
        self._mode_ack_decode = msgspec.msgpack.Decoder(mri.ModeAck).decode
        self.epoch = time.time()
        self.errors: deque[mri.ErrorEvent] = deque(maxlen=MAX_ERRORS)
        self.params = ParamDesk(manifest.robot)
        """Run-time parameter values and changes (``cromat param``, module_manager/params.py)."""
        self.router: Child | None = None
        self.processes: dict[str, Child] = {}
        self.session: zenoh.Session | None = None
        self._entities: list[Any] = []
        self._publishers: list[Publisher[Any]] = []
        self._mode_pubs: dict[str, Publisher[Any]] = {}
        self._state_pub: Publisher[mri.RobotState] | None = None
        self._mri_thread: threading.Thread | None = None
        self._state_dirty = True
        self.t0 = clock()
        self._waiting: set[str] = set()
        """Modules not started yet because a module they start ``after`` is not up yet."""
        self.all_up_at: float | None = None
        self._ack_decode = msgspec.msgpack.Decoder(RouteAck).decode
        self.route_drifts = 0  # routes found differing from the manager's view (module_manager/route_audit.py)
        self._beat_decode = msgspec.msgpack.Decoder(Heartbeat).decode
        proto = "tls" if manifest.pki is not None else "tcp"
        if proto == "tls" and not all(e.startswith("tls/") for e in self.listen):
            raise LaunchError(f"[bus.tls]: the router listens on tls/ endpoints only, not {', '.join(self.listen)}")
        connect = list(manifest.raw.bus.connect)
        if not connect:
            first = next((ep for e in self.listen if e.startswith(f"{proto}/") and (ep := tcp_endpoint(e))), None)
            if first is None:
                raise LaunchError(f"bus.listen has no {proto} endpoint and bus.connect is empty: "
                                  "the manager cannot tell its modules where the router is")
            connect = [f"{proto}/{first[0]}:{first[1]}"]
        self.connect = connect
        settings = lockstep.settings_for(manifest, connect, speed)
        self.sim = None if settings is None else lockstep.ManagerMember(settings)
        """The manager's part in a lockstep simulation (module_manager/lockstep.py), or None: the wall clock."""
        self._mri_busy = False
        self.next_state_at = 0.0
        for mod in self.modules.values():
            mod.sup.beat_clock = None if self.sim is None else self.sim.clock.monotonic
        self.runtime_dir: Path | None = None
        self.bus = self.bus_for(MANAGER_MODULE)
        self._peer_acl = bus_links.peer_access_control(self.m) if self.m.pki is not None else None
        """The ingress policy of every module's peer session under ``[bus] links = "peers"`` (bus_links.py)."""

    def bus_for(self, identity: str) -> SessionConfig:
        """The bus config of the manager or a module: plain client, or mTLS with that identity's certificate."""
        if self.m.pki is None:
            return SessionConfig(mode="client", connect=list(self.connect))
        return secure.client_bus(self.m, self.connect, identity)

    def module_bus_for(self, identity: str) -> SessionConfig:
        """A module's bus config: ``bus_for`` as a client of the router, or as a peer under ``[bus] links``."""
        return bus_links.module_bus(self.m, self.bus_for(identity), self._peer_acl)

    # ------------------------------------------------------------------------------------------ start-up

    def child_env(self, extra: dict[str, str]) -> dict[str, str]:
        env = dict(os.environ)
        paths = [str(p) for p in self.m.pythonpath] + [str(ROOT)]
        if env.get("PYTHONPATH"):
            paths.append(env["PYTHONPATH"])
        env["PYTHONPATH"] = os.pathsep.join(paths)
        env.update({k: self.expand(v) for k, v in extra.items()})
        if self.sim is not None:
            env.update(self.sim.env())
        return env

    def start_router(self) -> None:
        argv = [sys.executable, "-m", "bbcs.router"]
        for e in self.listen:
            argv += ["--listen", e]
        if self.m.raw.bus.zenoh_config:
            argv += ["--config", str(self.m.dir / self.m.raw.bus.zenoh_config)]
        elif self.m.pki is not None:
            self.runtime_dir = Path(tempfile.mkdtemp(prefix=f"cromat-{self.m.robot}-"))
            argv += ["--config", str(secure.write_router_config(self.m, self.listen, self.runtime_dir))]
        if self.m.raw.bus.admin_space:
            argv.append("--admin-space")
        if self.m.pki is not None and self.m.raw.bus.tls is not None and self.m.raw.bus.tls.acl:
            argv.append("--log-refusals")  # a secure robot's refusals go to the router's log (docs/security.md)
            argv += ["--revoked", str(self.m.pki / "revoked.txt")]  # a station revoked while it runs: denied at once
        for peer in self.m.raw.bus.peers:
            argv += ["--connect", self.expand(peer)]
        argv += ["--robot", self.m.robot]  # its Zenoh id from the name: the mesh refuses a second robot of it
        t = self.clock()
        self.router = Child("router", argv, self.child_env({}), cwd=str(ROOT), log_dir=self.log_dir,
                            watch_stdout=True, echo=self._router_line, cpus=_cpus(self.m.raw.bus.cpus),
                            priority=self._priority(self.m.raw.bus))
        host, port = next(ep for e in self.bus.connect if (ep := tcp_endpoint(e)))
        if not wait_tcp(host, port, self.m.raw.bus.ready_timeout_s, lambda: self.router.poll() is None):
            raise LaunchError(f"the router did not listen on {host}:{port} within "
                              f"{self.m.raw.bus.ready_timeout_s:g} s ("
                              + ("still starting: [bus] ready_timeout_s may be too short for this machine)"
                                 if (code := self.router.poll()) is None else f"it exited with code {code})"))
        self.out(f"  router      listening on {', '.join(self.listen)}{_on(self.m.raw.bus.cpus)} "
                 f"({self.clock() - t:.2f} s)")
        if self.router.priority_refused:
            self.out(f"  router      {self.router.priority_refused}")

    def _router_line(self, line: str) -> None:
        """The router's word that the mesh refused it (another robot of this name is linked there): shown on the
        launch's output, once per peer, besides the router's log (bbcs.router_audit)."""
        if line.startswith(FLOOD_LINE):
            self._router_flood(line)
        if not line.startswith(f"cromat router: {router_audit.MESH_REFUSED}: "):
            if self.log_dir is None:  # no router log: its lines go where they went before, our stdout
                sys.stdout.write(line + "\n")
                sys.stdout.flush()
            return
        said = line.rsplit(" (", 1)[0]  # without the running count
        if said not in self._mesh_refusals:
            self._mesh_refusals.add(said)
            self.out(f"  router      {said.removeprefix('cromat router: ')}")
            with self.lock:  # in the manager's state, so in the GRI state's errors: a station on this router sees it
                self.errors.append(mri.ErrorEvent(
                    module="router", code=int(RouterErrorCode.DUPLICATE_ROBOT_NAME),
                    name=RouterErrorCode.DUPLICATE_ROBOT_NAME.name, stamp=time.time(),
                    detail=said.removeprefix(f"cromat router: {router_audit.MESH_REFUSED}: ")))
                self._touch()

    def _router_flood(self, line: str) -> None:
        """A flood the router cut (bbcs/router_floods.py): into the manager's error list, so into the GRI state's
        errors, naming the identity and the key; at most one entry per identity and key every FLOOD_REPORT_S."""
        said = line.removeprefix(FLOOD_LINE)
        who_key = said.split(" put ", 1)[0] + " " + said.rsplit(" on ", 1)[-1].split(" over ", 1)[0]
        now = time.monotonic()
        if now - self._floods_said.get(who_key, -FLOOD_REPORT_S) < FLOOD_REPORT_S:
            return
        self._floods_said[who_key] = now
        with self.lock:
            self.errors.append(mri.ErrorEvent(
                module="router", code=int(RouterErrorCode.WRITE_FLOODED), name=RouterErrorCode.WRITE_FLOODED.name,
                stamp=time.time(), detail=said))
            self._touch()

    def start_processes(self) -> None:
        """Start every plain process (simulators) at once, then wait for each one's readiness: their start-up
        times overlap instead of adding up. Modules start only once all of them are ready."""
        t = self.clock()
        raised = raised_priorities({"router": self.m.raw.bus, **self.m.raw.processes,
                                    **{n: i.spec for n, i in self.m.modules.items()}})
        if self.sim is not None and raised:
            self.out(f"  lockstep: the raised priorities of {', '.join(raised)} are not applied (the simulation "
                     "waits for every module; a raised priority would only take the processors from the rest)")
        started: list[tuple[str, Any, list[str], Child]] = []
        for name, spec in self.m.raw.processes.items():
            argv = [self.expand(a) for a in spec.command]
            child = Child(name, argv, self.child_env(spec.env), cwd=str(self.m.dir), log_dir=self.log_dir,
                          watch_stdout=spec.ready.kind == "stdout", cpus=_cpus(spec.cpus),
                          priority=self._priority(spec))
            self.processes[name] = child
            if child.priority_refused:
                self.out(f"  {name:<11} {child.priority_refused}")
            started.append((name, spec, argv, child))
        for name, spec, argv, child in started:
            ready = spec.ready
            left = max(0.2, ready.timeout_s - (self.clock() - t))
            if ready.kind == "tcp":
                ok = wait_tcp(self.expand(ready.host), int(self.expand(ready.port)), left,
                              lambda c=child: c.poll() is None)
            elif ready.kind == "stdout":
                ok = child.wait_line(ready.pattern, left)
            else:
                ok = child.poll() is None
            if not ok:
                code = child.poll()
                raise LaunchError(f"process {name} ({' '.join(argv)}) not ready within {ready.timeout_s:g} s "
                                  f"(ready: {ready.kind}; " + ("still running, not ready yet)" if code is None
                                                              else f"it exited with code {code})"))
            self.out(f"  {name:<11} ready, pid {child.pid}{_on(spec.cpus)} ({self.clock() - t:.2f} s)")

    def open_bus(self) -> None:
        s = self.session = open_session(self.bus)
        robot = self.m.robot
        self._entities.append(s.liveliness().declare_subscriber(keys.alive_pattern(robot), self._on_alive,
                                                                history=True))
        for name, mod in self.modules.items():
            info = mod.info
            self._entities.append(s.declare_subscriber(
                keys.route_ack_key(robot, name), lambda smp, n=name: self._on_ack(n, _bytes(smp))))
            self._entities.append(s.declare_subscriber(
                keys.heartbeat_key(robot, name), lambda smp, n=name: self._on_beat(n, _bytes(smp))))
            if info.error_slot and info.error_type is not None:
                self._entities.append(s.declare_subscriber(
                    keys.slot_key(robot, name, info.error_slot), lambda smp, n=name: self._on_error(n, smp)))
            if info.control_type is not None:
                spec = SlotSpec(info.control_slot, info.control_type, Direction.OUT, Kind.STATE, Safety.SAFE)
                mod.control = Publisher(s, keys.slot_key(robot, name, info.control_slot), spec)
                self._publishers.append(mod.control)
                self._publish_control(mod)
        for name, mode in self.m.modes.items():
            if mode.ack:
                self._entities.append(s.declare_subscriber(
                    keys.slot_key(robot, mode.module, mri.MODE_ACK_SLOT),
                    lambda smp, n=mode.module: self._on_mode_ack(n, _bytes(smp))))
            spec = SlotSpec(name, mode.type, Direction.OUT, Kind.STATE, Safety.SAFE)
            pub = self._mode_pubs[name] = Publisher(s, keys.slot_key(robot, MANAGER_MODULE, name), spec)
            self._publishers.append(pub)
            if mode.initial is not None:
                pub.publish(mode.initial)
        number = self.m.raw.robot.telemetry_slot
        if number is not None:
            tdecode = msgspec.msgpack.Decoder(RobotTelemetry).decode
            self._entities.append(s.declare_subscriber(self.m.slot_table.slots[number].key(robot),
                                                       lambda smp: self._on_telemetry(tdecode, smp)))
        self._state_pub = Publisher(s, mri.mri_key(robot, mri.STATE),
                                    SlotSpec("state", mri.RobotState, Direction.OUT, Kind.STATE, Safety.SAFE))
        self._publishers.append(self._state_pub)
        queryable = s.declare_queryable(keys.manager_key(robot) + "/*")
        self._entities.append(queryable)
        self._entities.append(wire.declare_service_schemas(s, keys.manager_key(robot), lambda: {
            mri.mri_key(robot, mri.STATE): mri.RobotState,
            **{mri.mri_key(robot, v): {"request": mri.MriRequest, "reply": mri.MriReply} for v in mri.VERBS}}))
        self._mri_thread = threading.Thread(target=self._serve_mri, args=(queryable,), name="mri", daemon=True)
        self._mri_thread.start()
        if self.sim is not None:
            self.sim.join(s, self.sim_busy)

    def stamp(self) -> float:
        """Now on the robot's clock (seconds since 1970), for what the manager stamps (its errors, tasks, states):
        the simulation's time in lockstep, as every module and the RAL stamp. The RAL compares them: a module
        error fails the tasks started before it, a telemetry refusal stands until telemetry stamped after it; on
        the wall clock, behind simulated time, neither could happen at --speed max."""
        return time.time() if self.sim is None else self.sim.clock.time()

    def _priority(self, spec: Any) -> Priority | None:
        return _priority(spec, lockstep_on=self.sim is not None)

    def sim_busy(self) -> str:
        """Lockstep: what the manager must still do before the simulation may step ('' = nothing)."""
        if self.all_up_at is None:
            return "modules starting"
        back = lockstep.restarting({n: m.sup.phase for n, m in self.modules.items()},
                                   [n for n, m in self.modules.items()
                                    if m.sup.phase is Phase.STOPPING and m.sup.state == "restarting"])
        if back:
            return f"restarting {', '.join(back)}"
        if self._mri_busy:
            return "serving an MRI request"
        if self.sim is not None and (self._state_dirty or state_due(self.sim.clock.monotonic(), self.next_state_at)):
            # due at this simulated time: published now, from the ask (the loop would take up to its next wake)
            with self.lock:
                self._state_dirty = False
                self.next_state_at = self.sim.clock.monotonic() + self.m.raw.robot.state_period_s
                if self._state_pub is not None:
                    self._state_pub.publish(self.robot_state())
                self.sim.activity += 1  # a new datum out: at least one more round sees where it went
        return ""

    # ------------------------------------------------------------------------------------------ bus events

    def _on_alive(self, sample: zenoh.Sample) -> None:
        try:
            robot, name = keys.parse_alive_key(str(sample.key_expr))
        except Exception:
            return
        mod = self.modules.get(name)
        if mod is None or robot != self.m.robot:
            return
        with self.lock:
            if mod.sup.running:
                mod.sup.liveliness(self.clock(), sample.kind == zenoh.SampleKind.PUT)
                self._touch()

    def _on_ack(self, name: str, payload: bytes) -> None:
        try:
            ack = self._ack_decode(payload)
        except msgspec.MsgspecError:
            return
        with self.lock:
            mod = self.modules[name]
            if ack.restart_count != mod.run_count - 1:
                return  # from an earlier run of the module
            mod.last_ack = ack
            matches = ack.accepted and all(ack.routes.get(i) == n for i, n in mod.routes.items())
            drift = route_audit.route_drift(name, mod.routes, ack.routes) if ack.accepted else []
            if drift:  # the module reads routes the manager never set: say so, and set them again
                self.route_drifts += len(drift)
                self.out(f"manager: {route_audit.describe(drift)}")
                self._publish_control(mod)
            mod.sup.routes_acknowledged(self.clock(), matches)
            self._touch()

    def _on_mode_ack(self, name: str, payload: bytes) -> None:
        try:
            ack = self._mode_ack_decode(payload)
        except msgspec.MsgspecError:
            return
        with self.lock:
            self._mode_acks[name] = ack
            self.changed.notify_all()

    def _on_beat(self, name: str, payload: bytes) -> None:
        try:
            beat = self._beat_decode(payload)
        except msgspec.MsgspecError:
            return
        with self.lock:
            mod = self.modules[name]
            if mod.child is not None and beat.pid == mod.child.pid:
                mod.sup.heartbeat(self.clock())

    def _on_error(self, name: str, sample: zenoh.Sample) -> None:
        try:
            code = _decode_error(_bytes(sample)).code
        except msgspec.MsgspecError:
            return
        with self.lock:
            self.modules[name].last_error = code
            self.errors.append(mri.ErrorEvent(module=name, code=code, stamp=self.stamp()))
            self._touch()

    def _on_telemetry(self, decode: Callable[[bytes], RobotTelemetry], sample: zenoh.Sample) -> None:
        try:
            value = decode(_bytes(sample))
        except msgspec.MsgspecError:
            return
        with self.lock:
            self.telemetry = value
            if value.airborne is False and value.position is not None:
                self.home = value.position
            if self.sim is None:
                return
            self.sim.activity += 1
            # lockstep: a state per telemetry sample, published as it comes. The robot state due at a step is
            # published at the step's ask, and telemetry from the modules has no order with the stepper's time: the
            # state then carried the step's last sample or the one before, by chance, and the RAL judged different
            # samples run to run (a uQuad's tumble of 0.3 s was seen in one state or in two: its 604 at 0.59 or
            # 1.14 s). Every sample reaches the RAL, in order, whatever the timing.
            self.next_state_at = max(self.next_state_at, self.sim.clock.monotonic() + self.m.raw.robot.state_period_s)
            if self._state_pub is not None:
                self._state_pub.publish(self.robot_state())

    def _touch(self) -> None:
        self._state_dirty = True
        self.changed.notify_all()

    # ------------------------------------------------------------------------------------------ supervision

    def _spawn(self, mod: _Module, action: Spawn) -> None:
        info = mod.info
        ctx = ModuleContext(robot=self.m.robot, module=info.name, bus=self.module_bus_for(self.m.identity(info.name)),
                            slot_table=self.m.slot_table,
                            routes=dict(mod.routes), conf=str(self.m.conf),
                            params={**{k: self.expand(v) for k, v in info.spec.params.items()},
                                    **secure.ral_fleet_params(self.m, info.name),  # signed fleet tasks
                                    **self.params.overrides_of(info.name)},  # set at run time: kept on restarts
                            restart_count=action.restart_count)
        now = self.clock()
        mod.run_count = action.restart_count + 1
        mod.last_ack = None
        mod.kill_deadline = None
        if self._take_standby(mod, encode_context(ctx)):
            mod.sup.spawned(now)
            if self.all_up_at is None and mod.child is not None:
                self.out(f"  {info.name:<11} starting, pid {mod.child.pid}{_on(info.spec.cpus)} (imports done ahead)")
            if mod.child is not None and mod.child.priority_refused:
                self.out(f"  {info.name:<11} {mod.child.priority_refused}")
            return
        env = self.child_env(info.spec.env)
        env[CONTEXT_ENV] = encode_context(ctx)
        try:
            mod.child = Child(info.name, [sys.executable, "-m", info.spec.entry], env, cwd=str(self.m.dir),
                              log_dir=self.log_dir, cpus=_cpus(info.spec.cpus), priority=self._priority(info.spec))
        except OSError as exc:
            mod.child = None
            mod.sup.spawn_failed(now, f"cannot start: {exc}")
            return
        mod.sup.spawned(now)
        if self.all_up_at is None:
            self.out(f"  {info.name:<11} starting, pid {mod.child.pid}{_on(info.spec.cpus)}")
        if mod.child.priority_refused:
            self.out(f"  {info.name:<11} {mod.child.priority_refused}")

    def prewarm_modules(self) -> None:
        """Before the router: one standby per module, so every module's interpreter start and imports overlap the
        router's and the simulators' start-up instead of following them; each becomes its module at its first
        start (``_take_standby``), or is sent end of input at shutdown. A standby that cannot start leaves a cold
        start."""
        for mod in self.modules.values():
            try:
                mod.standby = self._start_standby(mod)
            except OSError as exc:
                self.out(f"manager: cannot start {mod.info.name} ahead: {exc}; it will start cold")

    def _start_standby(self, mod: _Module) -> Child:
        """A warm standby of ``mod`` (module_manager/standby.py): its interpreter and imports, waiting for a context."""
        return Child(mod.info.name, standby_argv(sys.executable, mod.info.spec.entry),
                     self.child_env(mod.info.spec.env), cwd=str(self.m.dir), log_dir=self.log_dir, stdin_pipe=True,
                     cpus=_cpus(mod.info.spec.cpus), priority=self._priority(mod.info.spec))

    def _take_standby(self, mod: _Module, context: str) -> bool:
        """Hand the context to the module's warm standby, which becomes the module; False if there is none alive."""
        standby, mod.standby = mod.standby, None
        if standby is None:
            return False
        if standby.poll() is None:
            try:
                standby.send_and_close_stdin(context_line(context))
                mod.child = standby
                mod.warm_starts += 1
                return True
            except OSError:  # it died between the poll and the write: reaped below, cold start instead
                pass
        standby.signal(signal.SIGKILL)
        standby.proc.wait()
        standby.close()
        return False

    def _keep_standby(self, mod: _Module) -> None:
        """Main thread: once the launch is up, keep one warm standby per up module whose policy asks for it; drop
        it when the module is stopped or failed. A standby that dies unused three times is not made again."""
        standby = mod.standby
        if standby is not None:
            if standby.poll() is not None:
                standby.close()
                mod.standby = None
                mod.standby_failures += 1
                self.out(f"manager: the standby of {mod.info.name} exited ({standby.poll()}) before it was needed")
            elif mod.sup.state in ("stopped", "failed"):
                self._drop_standby(mod)
            return
        policy = mod.info.policy
        if (policy.standby and policy.restart != "never" and mod.sup.phase is Phase.UP and self.all_up_at is not None
                and mod.standby_failures < 3 and not self.stop_event.is_set()):
            try:
                mod.standby = self._start_standby(mod)
            except OSError as exc:
                mod.standby_failures += 1
                self.out(f"manager: cannot start a standby of {mod.info.name}: {exc}")

    def _drop_standby(self, mod: _Module) -> None:
        """An unused standby has nothing to clean up: killed and reaped at once (the main loop does not wait)."""
        standby, mod.standby = mod.standby, None
        if standby is not None:
            standby.signal(signal.SIGKILL)
            standby.proc.wait()
            standby.close()

    def _perform(self, mod: _Module, actions: list[Spawn | Kill]) -> None:
        for action in actions:
            if isinstance(action, Spawn):
                self._spawn(mod, action)
            elif mod.child is not None:
                if action.graceful:
                    mod.child.signal(signal.SIGTERM)
                    mod.kill_deadline = self.clock() + self.m.stop_grace_s
                else:
                    mod.child.signal(signal.SIGKILL)

    def _start_ready_modules(self) -> None:
        """Start, all at once, every waiting module whose ``after`` modules are up (the first call: every module
        without dependencies); a module whose dependency failed is marked failed and never started."""
        if not self._waiting:
            return
        now = self.clock()
        after = {n: tuple(m.info.spec.after) for n, m in self.modules.items()}
        start, blocked = startable(self._waiting, after, {n: m.sup.phase for n, m in self.modules.items()})
        for name in start:
            self._waiting.discard(name)
            self.modules[name].sup.start(now)
        for name, reason in blocked.items():
            self._waiting.discard(name)
            self.modules[name].sup.blocked(reason)
            self._touch()

    def step(self) -> None:
        """Reap exits, tick every supervisor, escalate overdue stops; publish the state when it changed."""
        with self.lock:
            self._start_ready_modules()
            now = self.clock()
            for name, mod in self.modules.items():
                child = mod.child
                if child is not None:
                    code = child.poll()
                    if code is not None:
                        child.close()
                        mod.child = None
                        mod.sup.exited(now, code)
                        self._keep_without_streams(mod.info.name)
                        self._fail_tasks_using(mod.info.name, f"module {mod.info.name} exited ({code}): "
                                                              f"{mri.EFFECT_LOST}")
                        self._touch()
                    elif mod.kill_deadline is not None and now > mod.kill_deadline:
                        child.signal(signal.SIGKILL)
                        mod.kill_deadline = None
                self._check_links(name, mod, now)
                actions = mod.sup.tick(now)
                if actions:
                    self._perform(mod, actions)
                    self._touch()
                self._keep_standby(mod)
            self._report_changes()
            if self.all_up_at is None and all(m.sup.phase is Phase.UP for m in self.modules.values()):
                self.all_up_at = now
                self.out(f"all {len(self.modules)} modules up in {now - self.t0:.2f} s")
                self.print_status()

    def _check_links(self, name: str, mod: _Module, now: float) -> None:
        """A module waiting only for its direct links (``links = "peers"``) counts as up once the kernel's socket
        tables show a link between it and every module already up (looked at every ``MESH_POLL_S``); after
        ``MESH_WAIT_S`` it counts as up all the same, and the launch names the modules it has not linked to."""
        if not mod.sup.awaiting_links or mod.child is None:
            mod.links_since = None
            return
        if mod.links_since is None:
            mod.links_since = now
        elif now < mod.links_polled + MESH_POLL_S:
            return
        mod.links_polled = now
        pids = {n: m.child.pid for n, m in self.modules.items() if m.child is not None and m.sup.phase is Phase.UP}
        pids[name] = mod.child.pid
        apart = [pair for pair in direct_links.unlinked_pairs(pids) if name in pair]
        settled = direct_links.verdict(apart, now - mod.links_since, MESH_WAIT_S)
        if settled is None:
            return
        if settled:
            others = sorted(a if b == name else b for a, b in settled)
            self.out(f"  {name:<11} up without a direct link to {', '.join(others)} after {MESH_WAIT_S:g} s")
        mod.sup.links_formed(now)
        self._touch()

    def _keep_without_streams(self, module: str) -> None:
        """``module`` exited: its mode slots keep their value without the stream data it carried (a path), so the
        module restarted gets the mode and its state data but does not fly a path again (task_data.kept)."""
        for slot, mode in self.m.modes.items():
            value = self.modes.get(slot)
            if mode.module != module or value is None:
                continue
            left = kept(value, self.mode_streams.get(slot, frozenset()))
            if left != value:
                self.modes[slot] = left
                self._mode_pubs[slot].publish(msgspec.convert(left, mode.type))

    def _fail_tasks_using(self, module: str, detail: str) -> None:
        """A module the running tasks rely on went down: those tasks end as failed (their routes/modes restored
        off the main thread, which must not wait for acknowledgements)."""
        for changes in self.tasks.fail_needing({module}, self.task_lost_with, self.stamp(), detail):
            threading.Thread(target=self.apply_changes, args=(changes,), kwargs={"ending": True}, name="task-fail",
                             daemon=True).start()
        self._touch()

    def _report_changes(self) -> None:
        for name, mod in self.modules.items():
            line = self._status_line(name, mod)
            shown = f"{mod.sup.state}|{mod.sup.reason}|{mod.sup.unreachable}"
            if shown != mod.shown:
                mod.shown = shown
                if self.all_up_at is not None or mod.sup.phase in (Phase.FAILED, Phase.RESTARTING):
                    self.out(line)

    def _status_line(self, name: str, mod: _Module) -> str:
        sup = mod.sup
        state = sup.state + (" (unreachable)" if sup.unreachable else "")
        routes = " ".join(f"{i}={n}" for i, n in mod.routes.items()) or "-"
        pid = mod.child.pid if mod.child is not None else "-"
        tail = f"  {sup.reason}" if sup.reason else ""
        return f"  {name:<14} {state:<11} pid {pid!s:<7} restarts {sup.restarts}  routes {routes}{tail}"

    def print_status(self) -> None:
        with self.lock:
            for name, mod in self.modules.items():
                self.out(self._status_line(name, mod))
            for name, child in self.processes.items():
                code = child.poll()
                self.out(f"  {name:<14} {'running' if code is None else f'exited {code}':<11} pid {child.pid}")

    def module_status(self, name: str) -> mri.ModuleStatus:
        mod = self.modules[name]
        sup = mod.sup
        reason = sup.reason + ("; unreachable (liveliness lost)" if sup.unreachable else "")
        return mri.ModuleStatus(name=name, state=sup.state, pid=mod.child.pid if mod.child else None,  # type: ignore[arg-type]
                                restarts=sup.restarts, last_exit=sup.last_exit, reason=reason.lstrip("; "),
                                routes=dict(mod.routes), task_types=list(mod.info.spec.task_types),
                                last_error=mod.last_error)

    def robot_state(self) -> mri.RobotState:
        with self.lock:
            return mri.RobotState(robot=self.m.robot, kind=self.m.kind, stamp=self.stamp(), telemetry=self.telemetry,
                                  modules=[self.module_status(n) for n in self.modules], tasks=self.tasks.active(),
                                  ended=list(self.tasks.ended), task_version=self.tasks.version,
                                  task_epoch=self.epoch, errors=list(self.errors), home=self.home,
                                  param_changes=self.params.recent())

    # ------------------------------------------------------------------------------------------ main loop

    def run(self, *, once_up: bool = False, status_interval: float = 0.0) -> int:
        """Start everything, supervise until ``stop_event``; stop every child. Exit code for the CLI."""
        self.out(f"cromat launch: robot {self.m.robot} ({self.m.kind}), {len(self.modules)} modules, "
                 f"manifest {self.m.path}")
        code = 0
        try:
            if self.m.raw.bus.peers:
                peers = [self.expand(e) for e in self.m.raw.bus.peers]
                problem = unique_name.duplicate_name_problem(self.m.robot, peers, self.out,
                                                             tls=secure.router_tls(self.m) if self.m.pki else None)
                if problem is not None:
                    raise LaunchError(problem)
            self.prewarm_modules()
            self.start_router()
            self.open_bus()
            self.start_processes()
            with self.lock:
                self._waiting = set(self.modules)
                self._start_ready_modules()
            next_status = self.clock()
            while not self.stop_event.is_set():
                self.step()
                refused = self.launch_refused()
                if refused is not None:
                    raise LaunchError(refused)
                now = self.clock()
                state_now = now if self.sim is None else self.sim.clock.monotonic()  # due on the robot's clock
                if self._state_dirty or state_due(state_now, self.next_state_at):
                    self._state_dirty = False
                    self.next_state_at = state_now + self.m.raw.robot.state_period_s
                    if self._state_pub is not None:
                        self._state_pub.publish(self.robot_state())
                if status_interval > 0 and now >= next_status and self.all_up_at is not None:
                    if next_status > self.t0:
                        self.print_status()
                    next_status = now + status_interval
                if once_up and self.all_up_at is not None:
                    break
                if once_up and self.all_up_at is None and self._gave_up():
                    self.out("not every module came up: " + self.not_up_reasons())
                    code = 1
                    break
                self._sleep_until_event(0.02)
        except LaunchError as exc:
            self.out(f"cromat launch: {exc}")
            code = 1
        finally:
            self.shutdown()
        return code

    def _gave_up(self) -> bool:
        """Every module has settled and one of them is down for good. Read under the lock in one pass: a module
        promoted to up by a bus callback since the last ``step`` is up, not a failure (the next step counts the
        robot up). Reading the phases outside the lock once took a launch whose last module had just come up for
        one that gave up."""
        with self.lock:
            if self._waiting:
                return False
            return launch_gave_up(m.sup.phase for m in self.modules.values())

    def not_up_reasons(self) -> str:
        """Each module that is not up, with its state, last exit and the last line of its log: what a launch that
        gave up says, so the user sees which module failed and why without opening the logs."""
        with self.lock:
            down = [(n, m) for n, m in self.modules.items() if m.sup.phase is not Phase.UP]
        why = []
        for name, mod in down:
            sup = mod.sup
            log = self.log_dir / f"{name}.log" if self.log_dir is not None else None
            last = _last_line(log) if log is not None else ""
            why.append(f"{name} {sup.state}" + (f" ({sup.reason})" if sup.reason else "")
                       + (f"; its log ends: {last}" if last else ""))
        return "; ".join(why) or "none (a module went down after the others came up)"

    def launch_refused(self) -> str | None:
        """Why the launch must stop: a module refused its configuration before the robot was up (see
        :func:`config_refusals`); None once up, or while every module may still come up."""
        if self.all_up_at is not None:
            return None
        with self.lock:
            refused = config_refusals({n: (m.sup.phase, m.sup.last_exit) for n, m in self.modules.items()})
        if not refused:
            return None
        why = []
        for name in refused:
            log = self.log_dir / f"{name}.log" if self.log_dir is not None else None
            last = _last_line(log) if log is not None else ""
            why.append(f"module {name} exited {EXIT_CONFIG}: configuration error"
                       + (f" ({last})" if last else "") + (f", log {log}" if log is not None else
                                                            " (its message is above)"))
        return (f"{'; '.join(why)}: the robot is not started half-way, every module is stopped "
                f"(fix it; `cromat launch --check` checks each module's params and .conf)")

    def _sleep_until_event(self, timeout_s: float) -> None:
        """Sleep until a module process exits (its pidfd turns readable) or ``timeout_s``: a SIGKILLed module is
        reaped and respawned at once instead of at the next poll."""
        with self.lock:
            fds = [m.child.pidfd for m in self.modules.values() if m.child is not None and m.child.pidfd is not None]
        if not fds:
            self.stop_event.wait(timeout_s)
            return
        select.select(fds, [], [], timeout_s)

    def shutdown(self) -> None:
        """Stop modules (reverse manifest order), then processes, then the bus, then the router."""
        with self.lock:
            for mod in self.modules.values():
                mod.sup.stop(self.clock(), "manager shutting down")
            children = [m.child for m in reversed(list(self.modules.values())) if m.child is not None]
            standbys = [m.standby for m in self.modules.values() if m.standby is not None]
            for mod in self.modules.values():
                mod.standby = None
        for standby in standbys:  # end of input: an unused standby exits 0
            try:
                standby.send_and_close_stdin(b"")
            except OSError:
                pass
        if children:
            self.out(f"stopping {len(children)} modules")
        stop_children(children + standbys, self.m.stop_grace_s)
        with self.lock:
            for mod in self.modules.values():
                if mod.child is not None:
                    mod.sup.exited(self.clock(), mod.child.poll() or 0)
                    mod.child = None
        stop_children(list(reversed(list(self.processes.values()))), self.m.stop_grace_s)
        for entity in reversed(self._entities):
            try:
                entity.undeclare()
            except Exception:  # already gone with a closed session: nothing left to release
                pass
        self._entities.clear()
        if self.sim is not None:
            self.sim.close()
        for pub in self._publishers:
            pub.close()
        if self._mri_thread is not None:
            self._mri_thread.join(2.0)
        if self.session is not None:
            self.session.close()
            self.session = None
        if self.router is not None:
            stop_children([self.router], self.m.stop_grace_s)
            self.router = None
        if self.runtime_dir is not None:
            shutil.rmtree(self.runtime_dir, ignore_errors=True)
            self.runtime_dir = None
        self.out("stopped")



def task_modules(manifest: Manifest) -> dict[str, set[str]]:
    """Manifest task → the modules its effect relies on: those its routes and modes drive, and those that declare
    its task type (``task_types`` of a module entry)."""
    out: dict[str, set[str]] = {}
    for name, t in manifest.tasks.items():
        used = {target.partition(".")[0] for target in t.routes}
        used |= {manifest.modes[slot].module for slot in t.modes if slot in manifest.modes}
        used |= {m for m, info in manifest.modules.items() if t.type in info.spec.task_types}
        out[name] = used & set(manifest.modules)
    return out


def _bytes(sample: zenoh.Sample) -> bytes:
    return sample.payload.to_bytes()
