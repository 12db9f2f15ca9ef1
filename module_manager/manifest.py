"""The launch manifest (``bbcs_conf/*.toml``): decoded into typed structs and checked before anything starts.

Every mistake is a :class:`ManifestError` naming the file, the key (``modules.pan_tilt.routes.datos``), the
line where it can be found, and the reason. The format is documented in docs/manifest.md.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import re
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec

from bbcs import IGNORE, ConfDocument, ConfError, InvalidNameError, Kind, SlotRef, SlotTable, keys, load_conf
from bbcs.codec import resolve_type, type_name
from bbcs.contracts.errors import ErrorReport
from bbcs.contracts.robot import RobotTelemetry
from bbcs.lockstep import FOLLOWER_MEMBER
from module_manager.supervision import Policy

MANAGER_MODULE = "manager"
"""Module chunk of the manager's own slots (mode slots): ``cromat/<robot>/manager/<slot>``."""

_PORT_PLACEHOLDER = re.compile(r"\{port:[A-Za-z0-9_]+\}")
NonNeg = Annotated[float, msgspec.Meta(ge=0.0)]
Positive = Annotated[float, msgspec.Meta(gt=0.0)]
Nice = Annotated[int, msgspec.Meta(ge=-20, le=19)]
"""A process's nice value, -20 (first) to 19 (last): module_manager/process.py, ``Priority``."""
RealTime = Annotated[int, msgspec.Meta(ge=1, le=99)]
"""SCHED_RR priority of a process, 1-99 (module_manager/process.py, ``Priority``)."""


RENAMED_MODULES = {
    "ral.process": "ral.module",
    "modules.dsp.process": "modules.dsp.module",
    "modules.vision.process": "modules.vision.module",
    "modules.uquad.flight_module": "modules.uquad.module",
}
"""Python modules holding a module class that were renamed (issue 35: the class lives in ``module.py`` everywhere):
a manifest naming the old path is told the new one, at its line, before anything starts."""


class ManifestError(Exception):
    """A manifest is unreadable or wrong: ``file:line: key: reason``."""

    def __init__(self, message: str, *, path: str, key: str = "", line: int | None = None) -> None:
        self.message = message
        self.path = path
        self.key = key
        self.line = line
        super().__init__(str(self))

    def __str__(self) -> str:
        where = self.path + (f":{self.line}" if self.line is not None else "")
        return f"{where}: {self.key + ': ' if self.key else ''}{self.message}"


class _Section(msgspec.Struct, kw_only=True, forbid_unknown_fields=True, frozen=True):
    """Base of manifest sections: unknown keys are errors (a typo must not be ignored silently)."""


class RobotSection(_Section):
    name: str
    kind: str
    conf: str
    """The robot .conf file, relative to the manifest."""
    task_types: list[str] = msgspec.field(default_factory=lambda: ["perception", "movement", "pan_tilt"])
    telemetry_slot: int | None = None
    """Slot number carrying bbcs.contracts.robot:RobotTelemetry, folded into the robot state."""
    state_period_s: Positive = 1.0


class TlsSection(_Section):
    """``[bus.tls]``: the router requires mutual TLS; every process presents its own certificate."""

    pki: str
    """Folder written by ``cromat certs`` (relative to the manifest): ca.pem, router.*, manager.*, one pair per
    module identity."""
    acl: bool = True
    """Also enforce the access policy of :mod:`bbcs.acl` on the router (identities = certificate CNs)."""
    gcs: list[str] = msgspec.field(default_factory=lambda: ["gcs"])
    """Ground-station identities the policy lets submit tasks and swap routes."""
    ral: str = "ral"
    """The module that is the robot's RAL (it gets the RAL's rights in the policy, not a module's)."""
    mesh_robots: list[str] = msgspec.field(default_factory=list)
    """Robots whose routers link to this one directly over ``tls/`` (certificate CN ``router-<robot>``): each may
    write only its own robot's keys (docs/fleet.md, "A mesh over mutual TLS")."""
    hubs: list[str] = msgspec.field(default_factory=list)
    """Certificate CNs of hub (ground) routers: a ground station's rights plus every other robot's writes."""


class BusSection(_Section):
    listen: list[str] = msgspec.field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    """Endpoints of the robot router (``cromat launch`` starts it first)."""
    connect: list[str] = msgspec.field(default_factory=list)
    """Where the manager and modules connect; empty: derived from the first tcp ``listen`` endpoint."""
    zenoh_config: str | None = None
    """Zenoh JSON5 file for the router (access control, TLS), relative to the manifest."""
    ready_timeout_s: Positive = 30.0
    tls: TlsSection | None = None
    """Mutual TLS (and access control) on the router; see docs/manifest.md."""
    admin_space: bool = False
    """Let clients read the router's Zenoh admin space (``@/<zid>/router/**``), read-only."""
    peers: list[str] = msgspec.field(default_factory=list)
    """Other routers (robots', ground stations') this robot's router connects to: the fleet mesh, routed by Zenoh
    itself (docs/fleet.md). Before anything starts, the launch refuses a robot name already alive there."""
    cpus: list[Annotated[int, msgspec.Meta(ge=0)]] | None = None
    """Processors the robot's router runs on (as a module's ``cpus``); None: any the manager may use."""
    nice: Nice | None = None
    """The robot router's nice value (as a module's ``nice``); None: the manager's. Every datum between two modules
    crosses the router, an ABORT too: under load it must not wait behind the processes it serves."""
    links: Literal["router", "peers"] | None = None
    """How modules reach each other: ``"peers"`` (linked directly, the access policy enforced by each receiver) or
    ``"router"`` (through the router). Default: ``links.DEFAULT_LINKS`` (router); router with ``zenoh_config``."""


class SupervisionSection(_Section):
    restart: Literal["never", "on-failure", "always"] = "on-failure"
    backoff_s: Positive = 0.5
    backoff_max_s: Positive = 8.0
    intensity: Annotated[int, msgspec.Meta(ge=0)] = 5
    period_s: Positive = 10.0
    start_timeout_s: Positive = 20.0
    stop_grace_s: Positive = 5.0
    watchdog_s: NonNeg = 10.0
    unreachable_debounce_s: NonNeg = 1.0
    standby: bool = False


class SimSection(_Section):
    """``[sim]``: how a robot on simulators runs (docs/simulation.md, "Lockstep")."""

    lockstep: bool = False
    """The simulators step only once every module has handled the last step; everyone reads simulated time."""
    speed: Positive | Literal["max"] | None = None
    """Simulated seconds per wall second at most, or "max"; unset: each simulator's own ``--time-scale``
    (``cromat launch --speed`` overrides both)."""
    step_s: Annotated[float, msgspec.Meta(gt=0.0, le=1.0)] = 0.2
    """Simulated seconds between two barriers (each costs a few bus round trips to every module)."""
    deadline_s: Positive = 20.0
    """Wall seconds a step waits for a module before it goes on without it (a loaded machine may take seconds)."""
    fleet: list[str] = msgspec.field(default_factory=list)
    """Robots (this one among them, each launched with the same list) that step on one barrier: the first one's
    DSP simulator steps the fleet, the others' follow it. Their routers must be meshed (``[bus] peers``)."""


class SlotDef(_Section):
    number: Annotated[int, msgspec.Meta(ge=0)]
    module: str
    slot: str
    type: str
    robot: str | None = None


class ModuleDef(_Section):
    entry: str
    """Python module run as ``python -m <entry>``."""
    cls: str = msgspec.field(name="class")
    """``package.module:Class`` of the bbcs Module subclass (its inputs, CONTROL_ENTRADA and ERROR slot)."""
    params: dict[str, str] = msgspec.field(default_factory=dict)
    """Module parameters (``ModuleContext.params``); placeholders such as ``{port:dsp}`` are expanded."""
    routes: dict[str, int] = msgspec.field(default_factory=dict)
    task_types: list[str] = msgspec.field(default_factory=list)
    env: dict[str, str] = msgspec.field(default_factory=dict)
    identity: str | None = None
    """Certificate name under ``[bus.tls]`` (``<pki>/<identity>.pem``); default: the module's name."""
    after: list[str] = msgspec.field(default_factory=list)
    """Modules that must be up (and processes ready) before this one starts; the others start in parallel."""
    restart: Literal["never", "on-failure", "always"] | None = None
    backoff_s: Positive | None = None
    backoff_max_s: Positive | None = None
    intensity: Annotated[int, msgspec.Meta(ge=0)] | None = None
    period_s: Positive | None = None
    start_timeout_s: Positive | None = None
    watchdog_s: NonNeg | None = None
    standby: bool | None = None
    """Keep a warm standby process for fast restarts (default: ``[supervision] standby``)."""
    cpus: list[Annotated[int, msgspec.Meta(ge=0)]] | None = None
    """Processors the module (every thread of it, its standbys too) may run on; None: any the manager may use.
    Two modules that exchange latency-critical slots measure about twice as fast on one shared processor as on
    two (docs/performance.md, "Placing modules on processors")."""
    nice: Nice | None = None
    """The module's nice value (every thread of it, its standbys too); None: the manager's. A value the OS refuses
    (below the inherited nice without CAP_SYS_NICE or RLIMIT_NICE) is said at launch; the module runs all the same."""
    realtime: RealTime | None = None
    """SCHED_RR at this priority (1-99) where the OS allows it (CAP_SYS_NICE or RLIMIT_RTPRIO); refused: said at
    launch, the module runs under the normal policy."""
    write_hz: dict[str, Positive] = msgspec.field(default_factory=dict)
    """Output slot → the most puts a second a secured robot's router passes from this module on that slot's key
    (Zenoh's downsampling at the router's ingress, per link): a flood above is dropped where it enters and named in
    the router's log (issue 32)."""


class ReadyDef(_Section):
    kind: Literal["none", "tcp", "stdout"] = "none"
    port: str = ""
    """``tcp``: the port to find open on ``host`` (placeholders allowed)."""
    host: str = "127.0.0.1"
    pattern: str = ""
    """``stdout``: the first stdout line containing this text (empty: the first line)."""
    timeout_s: Positive = 10.0


class ProcessDef(_Section):
    command: list[str]
    ready: ReadyDef = msgspec.field(default_factory=ReadyDef)
    env: dict[str, str] = msgspec.field(default_factory=dict)
    cpus: list[Annotated[int, msgspec.Meta(ge=0)]] | None = None
    """Processors the process may run on (as a module's ``cpus``)."""
    nice: Nice | None = None
    """As a module's ``nice``."""
    realtime: RealTime | None = None
    """As a module's ``realtime``."""


class ModeDef(_Section):
    slot: str
    type: str
    module: str
    """The module this mode slot drives (``SetModuleMode.module``)."""
    initial: dict[str, int] | None = None
    ack: bool = False
    """The module answers every mode on its ``mode_ack`` slot (:class:`bbcs.contracts.mri.ModeAck`): the manager
    waits for that answer before it replies, so a refused mode is reported and data sent after the reply are
    handled under the new mode (docs/bus.md, "Mode and data in order")."""
    restore: bool = True
    """Ending a task re-publishes the value this slot had before it started. ``false`` for one-shot movement
    commands (take off, land, ...): a completed task leaves the module in the state it reached by itself."""


class TaskDef(_Section):
    type: str
    routes: dict[str, int] = msgspec.field(default_factory=dict)
    """``module.input`` → slot number."""
    modes: dict[str, dict[str, int]] = msgspec.field(default_factory=dict)
    """mode slot name → mode struct fields."""
    survives: list[str] = msgspec.field(default_factory=list)
    """Modules whose exit does not end this task: what it needed from them is already with the device (a mode-0
    path is in the DSP's queue, which flies on). They are still needed to start it."""


class ManifestFile(_Section):
    robot: RobotSection
    bus: BusSection = msgspec.field(default_factory=BusSection)
    supervision: SupervisionSection = msgspec.field(default_factory=SupervisionSection)
    sim: SimSection = msgspec.field(default_factory=SimSection)
    pythonpath: list[str] = msgspec.field(default_factory=list)
    slot: list[SlotDef] = msgspec.field(default_factory=list)
    modules: dict[str, ModuleDef] = msgspec.field(default_factory=dict)
    processes: dict[str, ProcessDef] = msgspec.field(default_factory=dict)
    mode: list[ModeDef] = msgspec.field(default_factory=list)
    tasks: dict[str, TaskDef] = msgspec.field(default_factory=dict)


@dataclass(frozen=True)
class ModuleInfo:
    """What the manager knows about one module once its class is imported."""

    name: str
    spec: ModuleDef
    policy: Policy
    control_type: type[msgspec.Struct] | None
    control_slot: str
    control_fields: dict[str, str]
    """CONTROL_ENTRADA field → input slot."""
    inputs: dict[str, str]
    """routed input slot → struct type name."""
    routes: dict[str, int]
    """initial route of every routed input (-1 where the manifest gives none)."""
    streams: frozenset[str]
    """routed inputs that are streams (each datum an event, never re-delivered: a path), not states."""
    error_slot: str | None
    error_type: type[msgspec.Struct] | None
    params_type: type[msgspec.Struct] | None = None
    """The class's ``params_type``: the struct its ``params`` load into (None: undeclared; ``cromat param``)."""
    runtime_params: frozenset[str] = frozenset()
    """The class's ``runtime_params``: the parameters it takes while running; every other one is start-up only."""


@dataclass(frozen=True)
class ModeSlot:
    name: str
    type: type[msgspec.Struct]
    module: str
    initial: msgspec.Struct | None
    ack: bool = False
    restore: bool = True


@dataclass(frozen=True)
class Manifest:
    """A checked manifest: everything the manager needs, with types resolved."""

    path: Path
    raw: ManifestFile
    robot: str
    kind: str
    conf: Path
    slot_table: SlotTable
    modules: dict[str, ModuleInfo]
    modes: dict[str, ModeSlot]
    tasks: dict[str, TaskDef]
    task_types: tuple[str, ...]
    stop_grace_s: float
    pythonpath: tuple[Path, ...]
    pki: Path | None = None
    """Absolute certificate folder under ``[bus.tls]``; None: plain TCP bus."""

    @property
    def dir(self) -> Path:
        return self.path.parent

    def identity(self, module: str) -> str:
        """Certificate name (CN) of a module: its ``identity`` key, else its instance name."""
        return self.modules[module].spec.identity or module


# ---------------------------------------------------------------------------------------------- loading


def load_manifest(path: str | Path, *, check_pki: bool = True) -> Manifest:
    """Read, decode and check a manifest; ManifestError on the first mistake (nothing is started here).

    ``check_pki=False`` skips the certificate files of ``[bus.tls]`` (``cromat certs --manifest`` creates them).
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ManifestError(f"cannot read manifest: {exc.strerror or exc}", path=str(p)) from exc
    return parse_manifest(text, p, check_pki=check_pki)


INCLUDE_KEY = "include"
"""Top-level key naming files (relative to the including file) whose values this manifest starts from."""


@dataclass(frozen=True)
class _Source:
    """One file of a manifest: its text, and the file that included it (None: the manifest launched)."""

    path: Path
    text: str
    included_by: Path | None = None


def _toml(text: str, path: Path, included_by: Path | None) -> dict[str, Any]:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        by = f" (included by {included_by})" if included_by is not None else ""
        raise ManifestError(f"not valid TOML{by}: {exc}", path=str(path),
                            line=int(m.group(1)) if m else None) from exc


def merge_tables(low: dict[str, Any], high: dict[str, Any]) -> dict[str, Any]:
    """``high`` over ``low``: a table present in both is merged key by key (deeply); any other value of ``high``
    (a string, a number, a list, an array of tables) replaces ``low``'s whole."""
    out = dict(low)
    for key, value in high.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge_tables(out[key], value)
        else:
            out[key] = value
    return out


def _with_includes(text: str, path: Path, chain: tuple[Path, ...] = (),
                   included_by: Path | None = None) -> tuple[dict[str, Any], list[_Source]]:
    """The file's values over those of the files it includes (in order, a later one over an earlier one), and
    its sources, most authoritative first (where a key is looked for to name its line)."""
    data = _toml(text, path, included_by)
    here = path.resolve()
    names = data.pop(INCLUDE_KEY, [])
    line = _locate(text, INCLUDE_KEY)
    if not (isinstance(names, list) and all(isinstance(n, str) and n for n in names)):
        raise ManifestError("must be a list of file names, e.g. include = [\"common.toml\"]", path=str(path),
                            key=INCLUDE_KEY, line=line)
    merged: dict[str, Any] = {}
    sources: list[_Source] = []
    for name in names:
        target = (path.parent / name).resolve()
        if target in (*chain, here):
            cycle = " -> ".join(str(p) for p in (*chain, here, target)[list((*chain, here)).index(target):])
            raise ManifestError(f"include cycle: {cycle}", path=str(path), key=INCLUDE_KEY, line=line)
        try:
            inc_text = target.read_text(encoding="utf-8")
        except OSError as exc:
            raise ManifestError(f"cannot read included file {target}: {exc.strerror or exc}", path=str(path),
                                key=INCLUDE_KEY, line=line) from exc
        inc_data, inc_sources = _with_includes(inc_text, target, (*chain, here), path)
        merged = merge_tables(merged, inc_data)
        sources = inc_sources + sources
    return merge_tables(merged, data), [_Source(path, text, included_by), *sources]


def _where(sources: list[_Source], key: str) -> tuple[str, int | None, str]:
    """(file, line, note) of ``key``: the first source (most authoritative) that writes it; else the launched file
    with its nearest table (the loader's best effort, as without includes). ``note`` names the including file."""
    for source in sources:
        line = _locate(source.text, key, exact=True)
        if line is not None:
            note = f" (in {source.path.name}, included by {source.included_by})" if source.included_by else ""
            return str(source.path), line, note
    return str(sources[0].path), _locate(sources[0].text, key), ""


def parse_manifest(text: str, path: Path, *, check_pki: bool = True) -> Manifest:
    data, sources = _with_includes(text, path)
    try:
        raw = msgspec.convert(data, ManifestFile)
    except msgspec.ValidationError as exc:
        text_exc = str(exc)
        where = text_exc.rpartition(" - at `")[2].rstrip("`") if " - at `" in text_exc else "$"
        msg = text_exc.partition(" - at `")[0]
        key = _named_entry(data, where.removeprefix("$").lstrip("."))
        if msg.startswith("Object contains unknown field"):
            unknown = msg.split("`")[1]
            key = f"{key}.{unknown}" if key else unknown
            msg = "unknown key (see docs/manifest.md for the keys allowed here)"
        elif msg.startswith("Object missing required field"):
            missing = msg.split("`")[1]
            key = f"{key}.{missing}" if key else missing
            msg = "required key missing"
        where, line, note = _where(sources, _dotted(key))
        raise ManifestError(msg + note, path=where, key=_dotted(key), line=line) from exc
    return _Checker(text, path, raw, check_pki, sources).check()


_NAMED_TABLES: dict[str, type[msgspec.Struct]] = {"modules": ModuleDef, "processes": ProcessDef, "tasks": TaskDef}


def _named_entry(data: dict[str, Any], key: str) -> str:
    """msgspec reports a bad entry of a named table as ``modules[...].cpus[0]``; put the name back in
    (``modules.sink.cpus[0]``) by decoding that table's entries one by one."""
    table, sep, rest = key.partition("[...]")
    if not sep or table not in _NAMED_TABLES or not isinstance(data.get(table), dict):
        return key
    for name, entry in data[table].items():
        try:
            msgspec.convert(entry, _NAMED_TABLES[table])
        except msgspec.ValidationError:
            return f"{table}.{name}{rest}"
    return key


def _dotted(key: str) -> str:
    """``modules.x[0]`` → ``modules.x.0`` (msgspec paths to TOML-ish keys)."""
    return re.sub(r"\[(\d+)\]", r".\1", key)


def _locate(text: str, key: str, *, exact: bool = False) -> int | None:
    """Best-effort line of ``key`` (dotted path) in the TOML text; None when it cannot be found (``exact``: None
    also when only an enclosing table is found)."""
    if not key:
        return None
    parts = key.split(".")
    lines = text.splitlines()
    header = re.compile(r"^\s*\[\[?\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")
    table: list[str] = []
    counts: dict[str, int] = {}
    best: int | None = None
    for i, line in enumerate(lines, 1):
        m = header.match(line)
        if m:
            name = m.group(1).replace('"', "")
            table = name.split(".")
            if line.lstrip().startswith("[["):
                counts[name] = counts.get(name, -1) + 1
                table = [*table, str(counts[name])]
            if table == parts[: len(table)]:
                best = i
                if table == parts:
                    return i
            continue
        rest = parts[len(table):] if table == parts[: len(table)] else None
        if rest:
            first = rest[0]
            if re.match(rf'^\s*"?{re.escape(first)}"?\s*=', line):
                return i
            if len(rest) > 1 and re.match(rf'^\s*"?{re.escape(first)}"?\s*\.', line):
                return i
    if exact:
        return None
    if best is None and parts:
        for i, line in enumerate(lines, 1):
            if re.match(rf'^\s*"?{re.escape(parts[-1])}"?\s*=', line):
                return i
    return best


class _Checker:
    """Cross-checks after decoding: names, files, types, slot numbers, routes, modes, tasks."""

    def __init__(self, text: str, path: Path, raw: ManifestFile, check_pki: bool = True,
                 sources: list[_Source] | None = None) -> None:
        self.text = text
        self.path = path
        self.raw = raw
        self.check_pki = check_pki
        self.conf_doc: ConfDocument | None = None
        self.sources = sources or [_Source(path, text)]

    def fail(self, key: str, message: str) -> ManifestError:
        where, line, note = _where(self.sources, key)
        return ManifestError(message + note, path=where, key=key, line=line)

    def sim_fleet(self, raw: ManifestFile) -> None:
        """``[sim] fleet``: a lockstep list of distinct robot names with this robot in it."""
        fleet = raw.sim.fleet
        if not fleet:
            return
        if not raw.sim.lockstep:
            raise self.fail("sim.fleet", "a fleet steps together only in lockstep: set [sim] lockstep = true")
        for i, robot in enumerate(fleet):
            self.name(robot, f"sim.fleet.{i}", "robot name")
        if len(set(fleet)) != len(fleet):
            raise self.fail("sim.fleet", f"a robot is named twice in {fleet}")
        if raw.robot.name not in fleet:
            raise self.fail("sim.fleet", f"this robot ({raw.robot.name}) is not in its own fleet {fleet}")
        if FOLLOWER_MEMBER in raw.modules or FOLLOWER_MEMBER in raw.processes:
            raise self.fail("sim.fleet", f"{FOLLOWER_MEMBER!r} is a fleet follower simulator's member name: "
                                         "rename the module or process of that name")

    def name(self, value: str, key: str, what: str) -> None:
        try:
            keys.validate_name(value, what)
        except InvalidNameError as exc:
            raise self.fail(key, str(exc)) from None

    def cpus(self, cpus: list[int] | None, key: str) -> None:
        """A ``cpus`` list names processors this launch may use (checked here, on the machine that launches: a
        child pinned to a processor that is not there could not start)."""
        if cpus is None:
            return
        if not cpus:
            raise self.fail(key, "an empty processor list: leave cpus out to let it run on any processor")
        allowed = os.sched_getaffinity(0)
        missing = sorted(set(cpus) - allowed)
        if missing:
            raise self.fail(key, f"processor{'s' if len(missing) > 1 else ''} {', '.join(map(str, missing))} not "
                                 f"available here (this launch may use {cpu_list(allowed)})")

    def type_(self, name: str, key: str) -> type[msgspec.Struct]:
        try:
            return resolve_type(name)
        except LookupError as exc:
            raise self.fail(key, str(exc)) from None

    def check(self) -> Manifest:
        raw = self.raw
        base = self.path.parent
        pythonpath = tuple((base / p).resolve() for p in raw.pythonpath)
        for p in pythonpath:
            if str(p) not in sys.path:
                sys.path.insert(0, str(p))
        self.name(raw.robot.name, "robot.name", "robot name")
        conf = (base / raw.robot.conf).resolve()
        if not conf.is_file():
            raise self.fail("robot.conf", f"robot .conf file {conf} does not exist")
        try:
            self.conf_doc = load_conf(conf)
        except ConfError as exc:
            raise self.fail("robot.conf", f"the robot .conf is malformed: {exc}") from None
        if raw.bus.zenoh_config is not None and not (base / raw.bus.zenoh_config).is_file():
            raise self.fail("bus.zenoh_config", f"Zenoh config file {base / raw.bus.zenoh_config} does not exist")
        if not raw.bus.listen:
            raise self.fail("bus.listen", "the router needs at least one listen endpoint")
        self.cpus(raw.bus.cpus, "bus.cpus")
        if raw.bus.links == "peers" and raw.bus.zenoh_config is not None:
            raise self.fail("bus.links", "links = \"peers\" cannot keep a hand-written router config's access rules "
                                         "(bus.zenoh_config) between modules: use [bus.tls] or links = \"router\"")
        if raw.sim.lockstep and (raw.bus.tls is not None or raw.bus.zenoh_config is not None):
            raise self.fail("sim.lockstep", "lockstep under access control is not built: the router's rules do not "
                                            "grant the @clock and @lockstep keys (docs/simulation.md)")
        self.sim_fleet(raw)
        for i, endpoint in enumerate(raw.bus.peers):
            if raw.bus.tls is None and not endpoint.startswith("tcp/"):
                raise self.fail(f"bus.peers.{i}", f"{endpoint!r}: without [bus.tls] the fleet mesh is built over tcp/ "
                                                  "endpoints (tls/ peers need [bus.tls], docs/fleet.md)")
            if raw.bus.tls is not None and not endpoint.startswith("tls/"):
                raise self.fail(f"bus.peers.{i}", f"{endpoint!r}: a secured robot ([bus.tls]) links to its peers over "
                                                  "tls/ only (mutual TLS, docs/fleet.md)")
        task_types = tuple(raw.robot.task_types)
        table = self.slot_table()
        modes = self.modes(table)
        modules = {name: self.module(name, spec, table, task_types) for name, spec in raw.modules.items()}
        for name, proc in raw.processes.items():
            self.name(name, f"processes.{name}", "process name")
            if name in modules or name == MANAGER_MODULE:
                raise self.fail(f"processes.{name}", "a process must not share its name with a module")
            if not proc.command:
                raise self.fail(f"processes.{name}.command", "empty command")
            if proc.ready.kind == "tcp" and not proc.ready.port:
                raise self.fail(f"processes.{name}.ready.port", "ready kind 'tcp' needs a port")
            self.cpus(proc.cpus, f"processes.{name}.cpus")
        self.start_order(modules)
        for mname, mode in modes.items():
            if mode.module not in modules:
                raise self.fail(f"mode.{mname}.module", f"mode slot {mname!r} drives unknown module {mode.module!r}")
        self.telemetry(table)
        tasks = {name: self.task(name, t, table, modules, modes, task_types) for name, t in raw.tasks.items()}
        pki = self.tls(modules)
        return Manifest(path=self.path.resolve(), raw=raw, robot=raw.robot.name, kind=raw.robot.kind, conf=conf,
                        slot_table=table, modules=modules, modes=modes, tasks=tasks, task_types=task_types,
                        stop_grace_s=raw.supervision.stop_grace_s, pythonpath=pythonpath, pki=pki)

    def start_order(self, modules: dict[str, ModuleInfo]) -> None:
        """``after``: every name is a module or a process of this manifest, not the module itself, and the
        dependencies have no cycle (a cycle would keep its modules from ever starting)."""
        known = set(modules) | set(self.raw.processes)
        for name, info in modules.items():
            for i, dep in enumerate(info.spec.after):
                key = f"modules.{name}.after"
                if dep == name:
                    raise self.fail(key, f"module {name} cannot start after itself")
                if dep not in known:
                    raise self.fail(key, f"after[{i}]: no module or process {dep!r} in this manifest "
                                         f"(modules: {', '.join(sorted(modules))}; processes: "
                                         f"{', '.join(sorted(self.raw.processes)) or 'none'})")
        cycle = find_cycle({n: [d for d in i.spec.after if d in modules] for n, i in modules.items()})
        if cycle:
            raise self.fail(f"modules.{cycle[0]}.after",
                            f"start dependency cycle: {' -> '.join(cycle)} (no module of it could ever start)")

    def tls(self, modules: dict[str, ModuleInfo]) -> Path | None:
        """``[bus.tls]``: tls/ listeners only, identities valid, every certificate file present."""
        tls = self.raw.bus.tls
        if tls is None:
            return None
        if self.raw.bus.zenoh_config is not None:
            raise self.fail("bus.zenoh_config", "bus.zenoh_config and [bus.tls] exclude each other: with [bus.tls] "
                                                "the router's Zenoh config is generated at launch")
        for i, endpoint in enumerate(self.raw.bus.listen):
            if not endpoint.startswith("tls/"):
                raise self.fail(f"bus.listen.{i}", f"{endpoint!r}: with [bus.tls] the router listens on tls/ only")
        for i, endpoint in enumerate(self.raw.bus.connect):
            if not endpoint.startswith("tls/"):
                raise self.fail(f"bus.connect.{i}", f"{endpoint!r}: with [bus.tls] clients connect over tls/ only")
        for i, name in enumerate(tls.gcs):
            self.name(name, f"bus.tls.gcs.{i}", "GCS identity")
        if not tls.gcs:
            raise self.fail("bus.tls.gcs", "at least one GCS identity is needed")
        reserved = {"ca": "the CA", "router": "the router", MANAGER_MODULE: "the manager",
                    **{g: "a ground station" for g in tls.gcs}}
        for name, info in modules.items():
            ident = info.spec.identity or name
            key = f"modules.{name}.identity" if info.spec.identity is not None else f"modules.{name}"
            self.name(ident, key, "identity")
            if ident in reserved:
                raise self.fail(key, f"identity {ident!r} is {reserved[ident]}'s: a module must not share it")
            reserved[ident] = f"module {name}"
        self.mesh(tls, reserved)
        pki = (self.path.parent / tls.pki).resolve()
        if not self.check_pki:
            return pki
        if not pki.is_dir():
            raise self.fail("bus.tls.pki", f"certificate folder {pki} does not exist (create it with "
                                           f"`cromat certs --manifest {self.path}`)")
        needed = [("bus.tls.pki", "ca.pem"), ("bus.tls.pki", "router.pem"), ("bus.tls.pki", "router.key"),
                  ("bus.tls.pki", f"{MANAGER_MODULE}.pem"), ("bus.tls.pki", f"{MANAGER_MODULE}.key")]
        for name, info in modules.items():
            ident = info.spec.identity or name
            key = f"modules.{name}.identity" if info.spec.identity is not None else f"modules.{name}"
            needed += [(key, f"{ident}.pem"), (key, f"{ident}.key")]
        for key, file in needed:
            if not (pki / file).is_file():
                raise self.fail(key, f"certificate file {pki / file} does not exist (create the certificates with "
                                     f"`cromat certs --manifest {self.path}`)")
        return pki

    def mesh(self, tls: TlsSection, reserved: dict[str, str]) -> None:
        """``mesh_robots`` and ``hubs``: valid, distinct names, not this robot nor a local identity; ``tls/``
        peers need someone listed (a router nobody listed would be denied everything)."""
        robot = self.raw.robot.name
        for i, name in enumerate(tls.mesh_robots):
            self.name(name, f"bus.tls.mesh_robots.{i}", "robot name")
            if name == robot:
                raise self.fail(f"bus.tls.mesh_robots.{i}", f"{name!r} is this robot: a robot is not its own mesh peer")
        if len(set(tls.mesh_robots)) != len(tls.mesh_robots):
            raise self.fail("bus.tls.mesh_robots", "a robot is listed twice")
        for i, name in enumerate(tls.hubs):
            key = f"bus.tls.hubs.{i}"
            self.name(name, key, "hub identity")
            if name in reserved:
                raise self.fail(key, f"identity {name!r} is {reserved[name]}'s: a hub must not share it")
            if name.startswith("router-"):
                raise self.fail(key, f"{name!r} looks like a robot router's identity (router-<robot>): list robots "
                                     "in bus.tls.mesh_robots")
            reserved[name] = "a hub"
        if self.raw.bus.peers and not (tls.mesh_robots or tls.hubs):
            raise self.fail("bus.peers", "a secured robot's peers must be listed by identity: the robots in "
                                         "bus.tls.mesh_robots, hub routers in bus.tls.hubs (docs/fleet.md)")

    def slot_table(self) -> SlotTable:
        seen: dict[int, int] = {}
        rows: dict[int, SlotRef] = {}
        for i, s in enumerate(self.raw.slot):
            key = f"slot.{i}"
            if s.number in seen:
                raise self.fail(f"{key}.number", f"slot number {s.number} is defined twice "
                                                 f"(first as slot[{seen[s.number]}])")
            seen[s.number] = i
            self.name(s.module, f"{key}.module", "module name")
            self.name(s.slot, f"{key}.slot", "slot name")
            if s.robot is not None:
                self.name(s.robot, f"{key}.robot", "robot name")
            cls = self.type_(s.type, f"{key}.type")
            rows[s.number] = SlotRef(module=s.module, slot=s.slot, type=type_name(cls), robot=s.robot)
        return SlotTable(robot=self.raw.robot.name, slots=rows)

    def slot_publishers(self, module: str, cls: Any) -> None:
        """Every ``[[slot]]`` of ``module`` names an output slot of its class, carrying the same struct type."""
        for i, s in enumerate(self.raw.slot):
            if s.module != module or (s.robot is not None and s.robot != self.raw.robot.name):
                continue
            spec = cls._outputs.get(s.slot)
            if spec is None:
                known = ", ".join(sorted(cls._outputs)) or "none"
                raise self.fail(f"slot.{i}.slot", f"module {s.module} ({type_name(cls)}) has no output slot "
                                                  f"{s.slot!r} (outputs: {known})")
            if type_name(spec.type) != type_name(self.type_(s.type, f"slot.{i}.type")):
                raise self.fail(f"slot.{i}.type", f"slot {s.number} is declared {s.type} but {s.module}/{s.slot} "
                                                  f"publishes {type_name(spec.type)} ({type_name(cls)})")

    def modes(self, table: SlotTable) -> dict[str, ModeSlot]:
        out: dict[str, ModeSlot] = {}
        for i, m in enumerate(self.raw.mode):
            key = f"mode.{i}"
            self.name(m.slot, f"{key}.slot", "slot name")
            if m.slot in out:
                raise self.fail(f"{key}.slot", f"mode slot {m.slot!r} is defined twice")
            cls = self.type_(m.type, f"{key}.type")
            number = table.number_of(MANAGER_MODULE, m.slot)
            if number is not None and table.slots[number].type != type_name(cls):
                raise self.fail(f"{key}.type", f"slot {number} ({MANAGER_MODULE}/{m.slot}) is declared as "
                                               f"{table.slots[number].type} in the slot table, not {type_name(cls)}")
            initial = None if m.initial is None else self.convert(m.initial, cls, f"{key}.initial")
            out[m.slot] = ModeSlot(name=m.slot, type=cls, module=m.module, initial=initial, ack=m.ack,
                                  restore=m.restore)
        return out

    def convert(self, value: dict[str, int], cls: type[msgspec.Struct], key: str) -> msgspec.Struct:
        try:
            return msgspec.convert(value, cls)
        except msgspec.ValidationError as exc:
            raise self.fail(key, f"not a valid {cls.__name__}: {exc}") from None

    def module(self, name: str, spec: ModuleDef, table: SlotTable, task_types: tuple[str, ...]) -> ModuleInfo:
        key = f"modules.{name}"
        self.name(name, key, "module name")
        if name == MANAGER_MODULE:
            raise self.fail(key, f"{MANAGER_MODULE!r} is the manager's own module name")
        if not _entry_exists(spec.entry):
            raise self.fail(f"{key}.entry", f"unknown module entry point {spec.entry!r}: no such Python module "
                                            "(or package without __main__)")
        from bbcs.module import Module  # the manager stands on bbcs; imported here to keep load cheap

        cls: Any = self._class(spec.cls, f"{key}.class")
        if not (isinstance(cls, type) and issubclass(cls, Module)):
            raise self.fail(f"{key}.class", f"{spec.cls!r} is not a bbcs Module subclass")
        self.slot_publishers(name, cls)
        self.cpus(spec.cpus, f"{key}.cpus")
        outputs = {s.name for s in getattr(cls, "slots", ()) if s.direction.value == "out" and s.peer is None}
        for slot in spec.write_hz:
            if slot not in outputs:
                raise self.fail(f"{key}.write_hz", f"write_hz: {slot!r} is not an output slot of {name} on its own "
                                                   f"key (outputs: {', '.join(sorted(outputs)) or 'none'})")
        conf_errors = getattr(cls, "conf_errors", None)  # the module's check of its part of the robot .conf
        problems = conf_errors(self.conf_doc) if callable(conf_errors) and self.conf_doc is not None else []
        if problems:
            raise self.fail("robot.conf", f"module {name} refuses the robot .conf ({len(problems)} errors):\n"
                                          + "\n".join(f"  {p}" for p in problems))
        self.params(name, cls, spec.params)
        for i, t in enumerate(spec.task_types):
            if t not in task_types:
                raise self.fail(f"{key}.task_types.{i}", f"unknown task type {t!r}; robot.task_types: "
                                                         f"{', '.join(task_types)}")
        control = cls.control
        fields = dict(control.routes) if control is not None else {}
        inputs = {slot: type_name(cls._inputs[slot].type) for slot in fields.values()}
        streams = frozenset(slot for slot in inputs if cls._inputs[slot].kind is Kind.STREAM)
        routes = {slot: IGNORE for slot in inputs}
        for slot, number in spec.routes.items():
            rkey = f"{key}.routes.{slot}"
            if slot not in inputs:
                known = ", ".join(sorted(inputs)) or "none"
                raise self.fail(rkey, f"{name} has no routed input {slot!r} (routed inputs: {known})")
            reason = route_problem(table, inputs[slot], number)
            if reason:
                raise self.fail(rkey, reason)
            routes[slot] = number
        error_slot = cls.error_slot
        error_type = cls._outputs[error_slot].type if error_slot else None
        if error_type is not None and error_type is not ErrorReport:
            raise self.fail(key, f"{name}: error slot {error_slot!r} carries {type_name(error_type)}, "
                                 f"not the one error shape {type_name(ErrorReport)}")
        s = self.raw.supervision
        policy = Policy(
            restart=spec.restart or s.restart, backoff_s=spec.backoff_s or s.backoff_s,
            backoff_max_s=spec.backoff_max_s or s.backoff_max_s,
            intensity=s.intensity if spec.intensity is None else spec.intensity,
            period_s=spec.period_s or s.period_s, start_timeout_s=spec.start_timeout_s or s.start_timeout_s,
            watchdog_s=s.watchdog_s if spec.watchdog_s is None else spec.watchdog_s,
            unreachable_debounce_s=s.unreachable_debounce_s,
            standby=s.standby if spec.standby is None else spec.standby)
        params_type = getattr(cls, "params_type", None)
        runtime = frozenset(getattr(cls, "runtime_params", frozenset()))
        if params_type is not None and not (isinstance(params_type, type) and issubclass(params_type, msgspec.Struct)):
            raise self.fail(f"{key}.class", f"{spec.cls}.params_type is not a msgspec struct")
        unknown = sorted(runtime - set(params_type.__struct_fields__ if params_type is not None else ()))
        if unknown:
            raise self.fail(f"{key}.class", f"{spec.cls}.runtime_params names {', '.join(unknown)}, not fields of "
                                            "its params_type")
        return ModuleInfo(name=name, spec=spec, policy=policy,
                          control_type=control.type if control is not None else None,
                          control_slot=control.slot if control is not None else "control_entrada",
                          control_fields=fields, inputs=inputs, routes=routes, streams=streams, error_slot=error_slot,
                          error_type=error_type, params_type=params_type, runtime_params=runtime)

    def params(self, name: str, cls: Any, params: dict[str, str]) -> None:
        """The module's check of its ``params`` (its class's ``param_errors`` hook, e.g. the RAL's): every problem,
        each at its manifest file:line (a module without the hook reads its params itself, unchecked here)."""
        param_errors = getattr(cls, "param_errors", None)
        # ``{port:NAME}`` is a free port chosen at launch: checked as one (the rest of the value as written)
        params = {key: _PORT_PLACEHOLDER.sub("1024", value) for key, value in params.items()}
        problems = list(param_errors(params)) if callable(param_errors) else []
        if not problems:
            return
        where = [(f"modules.{name}.params.{key}", reason) for key, reason in problems]
        first = self.fail(*where[0])
        if len(where) > 1:
            rest = [str(self.fail(key, reason)) for key, reason in where[1:]]
            first = ManifestError(first.message + f"\n  ({len(where)} parameter errors of module {name}; also:)\n  "
                                  + "\n  ".join(rest), path=first.path, key=first.key, line=first.line)
        raise first

    def _class(self, name: str, key: str) -> Any:
        module_name, sep, qualname = name.partition(":")
        if not sep:
            raise self.fail(key, f"{name!r} must be written 'package.module:Class'")
        if module_name in RENAMED_MODULES:
            new = RENAMED_MODULES[module_name]
            raise self.fail(key, f"{module_name!r} was renamed {new!r}: write '{new}:{qualname}'")
        try:
            obj: Any = importlib.import_module(module_name)
        except Exception as exc:
            raise self.fail(key, f"cannot import {module_name!r}: {exc}") from None
        for part in qualname.split("."):
            obj = getattr(obj, part, None)
            if obj is None:
                raise self.fail(key, f"module {module_name!r} has no {qualname!r}")
        return obj

    def telemetry(self, table: SlotTable) -> None:
        number = self.raw.robot.telemetry_slot
        if number is None:
            return
        ref = table.slots.get(number)
        if ref is None:
            raise self.fail("robot.telemetry_slot", f"slot {number} is not in the slot table")
        if ref.type != type_name(RobotTelemetry):
            raise self.fail("robot.telemetry_slot", f"slot {number} carries {ref.type}, "
                                                    f"not {type_name(RobotTelemetry)}")

    def task(self, name: str, t: TaskDef, table: SlotTable, modules: dict[str, ModuleInfo],
             modes: dict[str, ModeSlot], task_types: tuple[str, ...]) -> TaskDef:
        key = f"tasks.{name}"
        if t.type not in task_types:
            raise self.fail(f"{key}.type", f"unknown task type {t.type!r}; robot.task_types: {', '.join(task_types)}")
        for target, number in t.routes.items():
            rkey = f"{key}.routes.{target}"
            module, _, slot = target.partition(".")
            info = modules.get(module)
            if info is None or slot not in info.inputs:
                raise self.fail(rkey, f"{target!r} is not a routed input 'module.input' of this manifest")
            reason = route_problem(table, info.inputs[slot], number)
            if reason:
                raise self.fail(rkey, reason)
        for slot, value in t.modes.items():
            mode = modes.get(slot)
            if mode is None:
                raise self.fail(f"{key}.modes.{slot}", f"unknown mode slot {slot!r}")
            self.convert(value, mode.type, f"{key}.modes.{slot}")
        for i, module in enumerate(t.survives):
            if module not in modules:
                raise self.fail(f"{key}.survives.{i}", f"unknown module {module!r}; modules: {', '.join(modules)}")
        return t


def cpu_list(cpus: set[int] | frozenset[int]) -> str:
    """``{0, 1, 2, 5}`` as ``0-2, 5`` (the kernel's notation, as in ``/proc/<pid>/status``)."""
    runs: list[list[int]] = []
    for n in sorted(cpus):
        if runs and runs[-1][1] == n - 1:
            runs[-1][1] = n
        else:
            runs.append([n, n])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def find_cycle(after: dict[str, list[str]]) -> list[str]:
    """A dependency cycle as ``[a, b, ..., a]`` (names in ``after`` order), or ``[]`` when there is none."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(name: str) -> list[str]:
        state[name] = 1
        path.append(name)
        for dep in after.get(name, []):
            if state.get(dep) == 1:
                return [*path[path.index(dep):], dep]
            if dep not in state and (found := visit(dep)):
                return found
        path.pop()
        state[name] = 2
        return []

    for name in after:
        if name not in state and (found := visit(name)):
            return found
    return []


def route_problem(table: SlotTable, input_type: str, number: int) -> str:
    """Why ``number`` cannot feed an input of ``input_type`` ("" when it can): missing slot or other type."""
    if number == IGNORE:
        return ""
    ref = table.slots.get(number)
    if ref is None:
        return f"slot {number} is not in the slot table"
    if ref.type != input_type:
        return f"slot {number} ({ref.module}/{ref.slot}) carries {ref.type}, the input needs {input_type}"
    return ""


def _entry_exists(entry: str) -> bool:
    try:
        spec = importlib.util.find_spec(entry)
    except (ImportError, ValueError):
        return False
    if spec is None:
        return False
    if spec.submodule_search_locations is not None:
        try:
            return importlib.util.find_spec(f"{entry}.__main__") is not None
        except (ImportError, ValueError):
            return False
    return True
