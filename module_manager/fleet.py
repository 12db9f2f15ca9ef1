"""``cromat fleet FLEET.toml``: launch N simulated robots on this machine, each a ``cromat launch`` of its own
(its router, its Module Manager, its modules, its DSP simulator at its own home), their routers meshed by Zenoh.

A fleet manifest names one robot manifest and how to multiply it::

    [fleet]
    manifest = "uav1_sim.toml"     # every robot is this manifest, renamed (its .conf's ROBOT line too)
    robots = 10
    name = "uav{n:02d}"            # n = 1..robots
    home = [37.4117, -6.0025, 12.0]
    spacing_m = 60.0               # DSP simulator homes on a line eastwards
    drop = ["modules.vision", "tasks.track", "tasks.follow_vision_path"]   # sections left out
    time_scale = 1.0
    record = true                  # each DSP simulator records what it receives (run dir/<name>/dsp_record.jsonl)

More robots of other manifests (another kind: the uQuad) in ``[[fleet.group]]`` tables (``manifest``, ``robots``,
``name``, optionally ``drop`` and ``conf``), further along the same line; a robot without a DSP simulator gets its
home in its .conf's ``HOME_*`` lines (``bbcs_conf/fleet_mixed_sim.toml``).

Mesh: a star on a hub router that ``cromat fleet`` starts first (a ground router: ground stations connect to
it); every robot's router peers it (``[bus] peers``), Zenoh routing between routers.
What each robot gets is written under ``--run-dir`` (manifest, .conf, logs), checked before anything starts.

A secured fleet: ``manifest`` names a robot manifest with ``[bus.tls]`` (``uav1_secure.toml``; ``secure = true``
says so explicitly and is refused with a manifest without it). ``cromat fleet`` then runs ``cromat certs`` into
the run dir (a fleet CA in ``ca/``, each robot's identities in ``<name>/pki``, the ground station's pair in
``ground/``, the hub's pair and policy in ``hub/`` and ``hub.json5``), links every robot to the hub over
``tls/`` (``[bus.tls] hubs``) and starts the hub with mTLS and its policy (``hub = "hub"``: its identity).
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from bbcs import forward_stop_signals, keys
from bbcs.acl import MESH_ROUTER_PREFIX
from bbcs.geodesy import offset
from bbcs.net import free_port, wait_tcp
from module_manager.manifest import ManifestError, load_manifest
from module_manager.status_lines import print_line


class FleetError(ValueError):
    pass


@dataclass(frozen=True)
class FleetSpec:
    manifest: Path
    robots: int
    name: str = "uav{n:02d}"
    home: tuple[float, float, float] = (37.4117, -6.0025, 12.0)
    spacing_m: float = 60.0
    drop: tuple[str, ...] = ()
    time_scale: float = 1.0
    record: bool = True
    conf: tuple[tuple[str, str], ...] = ()
    """.conf lines set in every robot's renamed .conf (e.g. a longer DSP_ACK_TIMEOUT when ten simulators share
    a small machine)."""
    secure: bool = False
    """The robot manifest has ``[bus.tls]``: identities issued into the run dir, robots linked to the hub over
    ``tls/``, the hub started with mTLS and its policy."""
    hub: str = "hub"
    """A secured fleet's hub router identity (its certificate CN, each robot's ``[bus.tls] hubs``)."""
    gcs: tuple[str, ...] = ()
    """A secured fleet's ground-station identities (the robot manifest's ``[bus.tls] gcs``)."""
    groups: tuple[FleetSpec, ...] = ()
    """More robots of other manifests (``[[fleet.group]]``, e.g. uQuads beside the UAVs), meshed on the same hub,
    their homes further along the same line."""
    lockstep: bool = False
    """The robots step together on one barrier (each robot manifest gets ``[sim] lockstep = true`` and the fleet's
    names in ``fleet``; the first robot's DSP simulator steps them, docs/simulation.md "A fleet in lockstep")."""
    speed: float | str | None = None
    """A lockstep fleet's pace (``[sim] speed``): "max", simulated seconds per wall second, or None (the DSP
    simulators' ``time_scale``)."""

    @property
    def total(self) -> int:
        """Robots in the whole fleet, every group included."""
        return self.robots + sum(g.robots for g in self.groups)


def members(spec: FleetSpec) -> list[tuple[FleetSpec, int, int]]:
    """Every robot of the fleet as (its group's spec, its number n in the group, its place on the line from 0)."""
    out = [(spec, n, n - 1) for n in range(1, spec.robots + 1)]
    for group in spec.groups:
        out += [(group, n, len(out)) for n in range(1, group.robots + 1)]
    return out


GROUP_KEYS = {"manifest", "robots", "name", "drop", "conf"}
"""What a ``[[fleet.group]]`` sets; the rest (home line, spacing, time scale, record) is the fleet's."""


def load_fleet(path: Path) -> FleetSpec:
    try:
        raw = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise FleetError(f"{path}: {exc}") from exc
    f = raw.get("fleet")
    if not isinstance(f, dict):
        raise FleetError(f"{path}: no [fleet] table")
    unknown = set(f) - {"manifest", "robots", "name", "home", "spacing_m", "drop", "time_scale", "record", "conf",
                        "secure", "hub", "group", "lockstep", "speed"}
    if unknown:
        raise FleetError(f"{path}: unknown key(s) in [fleet]: {sorted(unknown)}")
    try:
        spec = FleetSpec(manifest=(path.parent / str(f["manifest"])).resolve(), robots=int(f["robots"]),
                         name=str(f.get("name", "uav{n:02d}")), home=tuple(float(x) for x in f.get(
                             "home", FleetSpec.home)),  # type: ignore[arg-type]
                         spacing_m=float(f.get("spacing_m", 60.0)), drop=tuple(f.get("drop", ())),
                         time_scale=float(f.get("time_scale", 1.0)), record=bool(f.get("record", True)),
                         conf=tuple((str(k), str(v)) for k, v in dict(f.get("conf", {})).items()))
    except (KeyError, TypeError, ValueError) as exc:
        raise FleetError(f"{path}: [fleet] {exc}") from exc
    if not 1 <= spec.robots <= 100:
        raise FleetError(f"{path}: [fleet] robots = {spec.robots}: 1..100 on one machine")
    if len(spec.home) != 3:
        raise FleetError(f"{path}: [fleet] home must be [lat, lon, alt]")
    spec = replace(spec, **_lockstep(path, f))
    spec = replace(spec, groups=_groups(path, f.get("group", []), spec))
    if spec.total > 100:
        raise FleetError(f"{path}: [fleet] {spec.total} robots in all: 1..100 on one machine")
    names = [robot_name(g, n) for g, n, _ in members(spec)]
    if len(set(names)) != len(names):
        twice = sorted({n for n in names if names.count(n) > 1})[0]
        raise FleetError(f"{path}: [fleet] name = {spec.name!r} gives one name to two robots ({twice!r}; the "
                         "name patterns of the fleet and its groups must give every robot its own name)")
    if spec.groups and f.get("secure", False):
        raise FleetError(f"{path}: [[fleet.group]]: a secured fleet of several robot manifests is not built "
                         "(docs/fleet.md); launch one manifest per secured fleet")
    return _secured(path, f, spec, names)


def _lockstep(path: Path, f: dict) -> dict[str, object]:
    """``lockstep`` and ``speed`` of ``[fleet]``, refused naming the file and key."""
    lockstep = f.get("lockstep", False)
    if not isinstance(lockstep, bool):
        raise FleetError(f"{path}: [fleet] lockstep = {lockstep!r}: true or false")
    speed = f.get("speed")
    if speed is not None:
        if not lockstep:
            raise FleetError(f"{path}: [fleet] speed: a pace for a fleet in lockstep only (set lockstep = true)")
        if speed != "max" and (isinstance(speed, bool) or not isinstance(speed, (int, float)) or not speed > 0):
            raise FleetError(f"{path}: [fleet] speed = {speed!r}: \"max\" or a positive number")
    return {"lockstep": lockstep, "speed": speed}


def _groups(path: Path, raw: object, fleet: FleetSpec) -> tuple[FleetSpec, ...]:
    """The ``[[fleet.group]]`` tables, each refused naming the file and the group's index and key."""
    if not isinstance(raw, list):
        raise FleetError(f"{path}: [fleet] group: write each group as a [[fleet.group]] table")
    groups = []
    for i, g in enumerate(raw):
        where = f"{path}: [[fleet.group]] {i + 1}"
        if not isinstance(g, dict):
            raise FleetError(f"{where}: a table of {sorted(GROUP_KEYS)}")
        unknown = set(g) - GROUP_KEYS
        if unknown:
            raise FleetError(f"{where}: unknown key(s) {sorted(unknown)} (a group sets {sorted(GROUP_KEYS)}; the "
                             "home line, spacing, time scale and record are the fleet's)")
        for key in ("manifest", "robots", "name"):
            if key not in g:
                raise FleetError(f"{where}: no {key}")
        try:
            group = replace(fleet, manifest=(path.parent / str(g["manifest"])).resolve(), robots=int(g["robots"]),
                            name=str(g["name"]), drop=tuple(g.get("drop", ())),
                            conf=tuple((str(k), str(v)) for k, v in dict(g.get("conf", {})).items()))
        except (TypeError, ValueError) as exc:
            raise FleetError(f"{where}: {exc}") from exc
        if not 1 <= group.robots <= 100:
            raise FleetError(f"{where}: robots = {group.robots}: 1..100 on one machine")
        try:
            base = load_manifest(group.manifest, check_pki=False)
        except ManifestError as exc:
            raise FleetError(f"{where}: manifest: {exc}") from exc
        if base.raw.bus.tls is not None:
            raise FleetError(f"{where}: manifest {group.manifest} has [bus.tls]: a secured fleet of several robot "
                             "manifests is not built (docs/fleet.md)")
        groups.append(group)
    return tuple(groups)


def _secured(path: Path, f: dict, spec: FleetSpec, names: list[str]) -> FleetSpec:
    """``spec`` made secure when its robot manifest has ``[bus.tls]``; an inconsistent secured fleet is refused
    naming the fleet file and key."""
    try:
        base = load_manifest(spec.manifest, check_pki=False)
    except ManifestError as exc:
        raise FleetError(f"{path}: [fleet] manifest: {exc}") from exc
    tls = base.raw.bus.tls
    secure = f.get("secure", tls is not None)
    if not isinstance(secure, bool):
        raise FleetError(f"{path}: [fleet] secure = {secure!r}: true or false")
    if secure and tls is None:
        raise FleetError(f"{path}: [fleet] secure = true but manifest {spec.manifest} has no [bus.tls] (point "
                         "manifest at a secured robot manifest, e.g. uav1_secure.toml)")
    if not secure and tls is not None:
        raise FleetError(f"{path}: [fleet] secure = false but manifest {spec.manifest} has [bus.tls]: a secured "
                         "robot is not launched unsecured (use uav1_sim.toml)")
    if tls is None:
        if "hub" in f:
            raise FleetError(f"{path}: [fleet] hub: a hub identity is for a secured fleet only")
        return spec
    for key in ("hubs", "mesh_robots"):
        if getattr(tls, key):
            raise FleetError(f"{path}: [fleet] manifest: {spec.manifest}: bus.tls.{key} is set; a fleet links its "
                             "robots to its own hub (leave it empty)")
    dropped = {"bus", "bus.tls"} & set(spec.drop)
    if dropped:
        raise FleetError(f"{path}: [fleet] drop: {sorted(dropped)[0]!r}: a secured fleet keeps [bus.tls]")
    hub = f.get("hub", "hub")
    if not isinstance(hub, str):
        raise FleetError(f"{path}: [fleet] hub = {hub!r}: the hub router's identity, a name")
    try:
        keys.validate_name(hub, "hub identity")
    except ValueError as exc:
        raise FleetError(f"{path}: [fleet] hub: {exc}") from exc
    taken = {**{n: "a robot's name" for n in names}, **{g: "a ground station's identity" for g in tls.gcs},
             **{base.identity(m): f"module {m}'s identity" for m in base.modules},
             "ca": "the CA's", "router": "a robot router's", "manager": "the manager's identity"}
    if hub in taken or hub.startswith(MESH_ROUTER_PREFIX):
        why = taken.get(hub, "a robot router's identity (router-<robot>)")
        raise FleetError(f"{path}: [fleet] hub = {hub!r} is {why}: the hub needs its own identity")
    return replace(spec, secure=True, hub=hub, gcs=tuple(tls.gcs))


def robot_name(spec: FleetSpec, n: int) -> str:
    return spec.name.format(n=n)


def drop_sections(text: str, headers: set[str]) -> str:
    """The manifest without these TOML tables (each up to the next table header)."""
    out, skip = [], False
    for line in text.splitlines(keepends=True):
        s = line.strip()
        if s.startswith("[") and not s.startswith("[["):
            skip = s.strip("[]") in headers
        elif s.startswith("[["):
            skip = False
        if not skip:
            out.append(line)
    return "".join(out)


def robot_manifest(spec: FleetSpec, n: int, run_dir: Path, peers: list[str], place: int | None = None,
                   fleet: Sequence[str] = ()) -> Path:
    """Write robot ``n``'s manifest (and its renamed .conf) under ``run_dir/<name>``; returns the manifest. Its home
    is ``place`` (default ``n - 1``) spacings east of the fleet's: the DSP simulator's ``--home``, or for a robot
    without one (the uQuad) its .conf's ``HOME_LAT``/``HOME_LON``/``HOME_ALT``, which its simulator starts from.
    ``fleet``: every robot's name, for a fleet in lockstep (``[sim] fleet``). A secured fleet's robot gets its pki
    folder ``run_dir/<name>/pki`` and the hub in ``[bus.tls] hubs`` (its
    certificates are issued after: :func:`issue_identities`)."""
    name = robot_name(spec, n)
    folder = run_dir / name
    folder.mkdir(parents=True, exist_ok=True)
    text = spec.manifest.read_text()
    base = load_manifest(spec.manifest, check_pki=False)  # a secured base: its certificates are not needed
    conf_src: Path | None = base.conf
    east = ((n - 1) if place is None else place) * spec.spacing_m
    lat, lon, alt = spec.home
    lat, lon = offset(lat, lon, 0.0, east)
    has_dsp_sim = re.search(r'(?m)^command = \[[^\n]*"modules\.dsp\.sim"', text) is not None
    text, k = re.subn(r'(\[robot\][^\[]*?\nname = )"[^"]*"', rf'\g<1>"{name}"', text, count=1)
    if k != 1:
        raise FleetError(f"{spec.manifest}: no [robot] name to rename")
    if conf_src is not None:
        conf_text = conf_src.read_text()
        conf_text, k = re.subn(r"(?m)^ROBOT:.*$", f"ROBOT: {name}", conf_text, count=1)
        if k != 1:
            raise FleetError(f"{conf_src}: no ROBOT line to rename")
        homes = () if has_dsp_sim else (("HOME_LAT", f"{lat:.6f}"), ("HOME_LON", f"{lon:.6f}"),
                                        ("HOME_ALT", f"{alt:g}"))
        # files the .conf names relative to itself (the uQuad's IMU calibration, its control gains): each robot
        # gets its own copy beside its renamed .conf, as each real robot has its own
        for m in re.finditer(r"(?m)^[A-Z][A-Z0-9_]*:[ \t]*([^\s#]+)", conf_text):
            ref = Path(m.group(1))
            if not ref.is_absolute() and (conf_src.parent / ref).is_file():
                (folder / ref).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(conf_src.parent / ref, folder / ref)
        # a robot that logs data files (the uQuad's loggers: LOG_DIR) logs them in its own run folder
        conf_text = re.sub(r"(?m)^LOG_DIR:.*$", f"LOG_DIR: {folder / 'data'}", conf_text, count=1)
        for key, value in homes:
            conf_text, k = re.subn(rf"(?m)^{key}:.*$", f"{key}: {value}", conf_text, count=1)
            if k != 1:
                raise FleetError(f"{conf_src}: no DSP simulator in {spec.manifest} and no {key} line in its .conf: "
                                 f"no way to give robot {name} its home")
        for key, value in spec.conf:
            if not re.fullmatch(r"[A-Z][A-Z0-9_]*", key):
                raise FleetError(f"[fleet] conf: {key!r} is not a .conf key")
            conf_text, k = re.subn(rf"(?m)^{key}:.*$", f"{key}: {value}", conf_text, count=1)
            if k == 0:
                conf_text += f"\n{key}: {value}\n"
        conf = folder / f"{name}.conf"
        conf.write_text(conf_text)
        text = re.sub(r'(\[robot\][^\[]*?\nconf = )"[^"]*"', rf'\g<1>"{conf}"', text, count=1)
    endpoints = ", ".join(f'"{p}"' for p in peers)
    text = re.sub(r"(?m)^peers = .*\n", "", text)
    text = text.replace("[bus]\n", f"[bus]\npeers = [{endpoints}]\n", 1)
    extra = [f'"--home", "{lat:.6f},{lon:.6f},{alt:g}"', f'"--time-scale", "{spec.time_scale:g}"']
    if spec.record:
        extra.append(f'"--record", "{folder / "dsp_record.jsonl"}"')
    if has_dsp_sim:
        text, k = re.subn(r'(?m)^(command = \[[^\n]*"modules\.dsp\.sim"[^\n]*?)\]\s*$',
                          lambda m: m.group(1) + ", " + ", ".join(extra) + "]", text, count=1)
        if k != 1:
            raise FleetError(f"{spec.manifest}: the DSP simulator's command must fit on one line to give it a home")
    elif conf_src is None:
        raise FleetError(f"{spec.manifest}: no DSP simulator and no .conf: no way to give robot {name} its home")
    text = re.sub(r'(?m)^(ready = \{ kind = "stdout", pattern = "socket://", timeout_s = )[0-9.]+',
                  r"\g<1>60.0", text)  # ten simulators starting on one small machine: more time to be ready
    text = drop_sections(text, set(spec.drop))
    if spec.lockstep:
        if not has_dsp_sim:
            raise FleetError(f"robot {name}: {spec.manifest} has no DSP simulator: only robots on DSP simulators "
                             "step together (a uQuad in a lockstep fleet is not built, docs/simulation.md)")
        if re.search(r"(?m)^\[sim\]\s*$", text):
            raise FleetError(f"robot {name}: {spec.manifest} has its own [sim] table: a fleet in lockstep sets it "
                             "([fleet] lockstep and speed)")
        listed = ", ".join(f'"{r}"' for r in fleet)
        pace = "" if spec.speed is None else f"speed = {json.dumps(spec.speed)}\n"  # "max" or a number, as TOML
        text = text.replace("[bus]\n", f"[sim]\nlockstep = true\n{pace}fleet = [{listed}]\n\n[bus]\n", 1)
    if spec.secure:
        text = re.sub(r"(?m)^(hubs|mesh_robots) = .*\n", "", text)
        text, k = re.subn(r'(?m)^pki = "[^"]*"', f'pki = "{folder / "pki"}"', text, count=1)
        if k != 1 or "[bus.tls]\n" not in text:
            raise FleetError(f"{spec.manifest}: no [bus.tls] pki line to point at the run dir")
        text = text.replace("[bus.tls]\n", f'[bus.tls]\nhubs = ["{spec.hub}"]\n', 1)
    path = folder / f"{name}.toml"
    path.write_text(text)
    try:
        load_manifest(path, check_pki=False)
    except ManifestError as exc:
        raise FleetError(f"robot {name}: {exc}") from exc
    return path


@dataclass(frozen=True)
class FleetPki:
    """Where a secured fleet's identities went (all under the run dir; generated, never committed)."""

    ca: Path
    """The fleet CA's folder (``ca.key``: the operator's, never in a robot's folder)."""
    ground: Path
    """The ground stations' pairs (``<gcs>.pem``/``.key``) and ``ca.pem``."""
    hub: Path
    """The hub router's pair (``<hub>.pem``/``.key``) and ``ca.pem``."""
    hub_config: Path
    """The hub router's Zenoh config: mTLS and its policy (:func:`bbcs.acl.hub_config`)."""

    def station(self, gcs: str) -> tuple[Path, Path, Path]:
        """(ca, cert, key) of ground station ``gcs``."""
        return self.ground / "ca.pem", self.ground / f"{gcs}.pem", self.ground / f"{gcs}.key"


def run_certs(argv: list[str]) -> None:
    """``cromat certs ARGV`` as a user runs it (cromat/certs.py: the one place identities are issued)."""
    proc = subprocess.run([sys.executable, "-m", "cromat.certs", *argv], capture_output=True, text=True)
    if proc.returncode != 0:
        raise FleetError(f"cromat certs {' '.join(argv)}: {proc.stderr.strip() or proc.stdout.strip()}")


def issue_identities(spec: FleetSpec, run_dir: Path, names: list[str], manifests: list[Path],
                     hub_listen: str) -> FleetPki:
    """A secured fleet's identities, issued by ``cromat certs`` from one fleet CA: each robot's as ``cromat certs
    --manifest`` issues them for one robot (router ``router-<robot>``, manager, its modules and RAL), the ground
    stations', and the hub's pair with its policy (``cromat certs --hub --robots --acl``). Then every robot
    manifest is checked with its certificates."""
    pki = FleetPki(ca=run_dir / "ca", ground=run_dir / "ground", hub=run_dir / "hub",
                   hub_config=run_dir / "hub.json5")
    for manifest in manifests:
        run_certs(["--manifest", str(manifest), "--ca", str(pki.ca), "--ground", str(pki.ground)])
    gcs = [arg for g in spec.gcs for arg in ("--gcs", g)]
    run_certs([str(pki.hub), "--hub", spec.hub, "--ca", str(pki.ca), "--robots", ",".join(names), "--acl",
               str(pki.hub_config), "--listen", hub_listen, *gcs])
    for name, manifest in zip(names, manifests, strict=True):
        try:
            load_manifest(manifest)
        except ManifestError as exc:
            raise FleetError(f"robot {name}: {exc}") from exc
    return pki


class Fleet:
    """The running fleet: one ``cromat launch`` child per robot, its output prefixed with the robot's name."""

    def __init__(self, spec: FleetSpec, run_dir: Path, out=print) -> None:  # type: ignore[no-untyped-def]
        self.spec = spec
        self.run_dir = run_dir
        self.out = out
        who = members(spec)
        self.ports = [0 for _ in who]  # each robot's own listen port, picked as it is started (_start_one)
        self.hub_port = free_port()
        self.scheme = "tls" if spec.secure else "tcp"
        self.hub_endpoint = f"{self.scheme}/127.0.0.1:{self.hub_port}"
        self.names = [robot_name(g, n) for g, n, _ in who]
        self.manifests = [robot_manifest(g, n, run_dir, [self.hub_endpoint], place, self.names)
                          for g, n, place in who]
        self.pki = issue_identities(spec, run_dir, self.names, self.manifests, self.hub_endpoint) if spec.secure \
            else None
        self.hub: subprocess.Popen | None = None
        self.hub_log = run_dir / "hub.log"
        self.batch = 5
        self.by_index: dict[int, subprocess.Popen] = {}
        self.attempts: dict[int, int] = {}
        self.max_attempts = 3
        """A launch that exits before its robot is up (a loaded machine: its router or simulator not ready in
        time) is started again, up to this many times in all."""
        self.procs: list[subprocess.Popen] = []
        self.up: set[str] = set()
        self.cond = threading.Condition()

    def start(self, timeout_s: float = 300.0) -> None:
        if self.pki is None:
            self.hub = subprocess.Popen([sys.executable, "-m", "bbcs.router", "--listen", self.hub_endpoint],
                                        stdout=subprocess.DEVNULL)
        else:  # mTLS and the hub's policy; its refusals logged (run dir/hub.log)
            with self.hub_log.open("w") as log:
                self.hub = subprocess.Popen([sys.executable, "-m", "bbcs.router", "--config", str(self.pki.hub_config),
                                             "--listen", self.hub_endpoint, "--log-refusals"],
                                            stdout=log, stderr=subprocess.STDOUT)
        if not wait_tcp("127.0.0.1", self.hub_port, 30):
            raise FleetError(f"the hub router does not listen on 127.0.0.1:{self.hub_port}")
        for first in range(0, len(self.names), self.batch):  # a few at a time: a small machine starts them all
            batch = range(first, min(first + self.batch, len(self.names)))
            for i in batch:
                self._start_one(i)
            self._wait({self.names[i] for i in batch}, timeout_s)

    def _start_one(self, i: int) -> None:
        name = self.names[i]
        # The robot's own listen port is picked now, not when the fleet was planned, and again on every attempt: a
        # port picked early can meanwhile be taken by another robot's outgoing connection (the same ephemeral
        # range), and then the launch's manager cannot reach its own router however often it is started.
        self.ports[i] = free_port()
        proc = subprocess.Popen(
            [sys.executable, "-m", "module_manager.cli", str(self.manifests[i]), "--listen",
             f"{self.scheme}/127.0.0.1:{self.ports[i]}", "--log-dir", str(self.run_dir / name / "logs")],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)  # in the fleet's process group
        self.procs.append(proc)
        self.by_index[i] = proc
        self.attempts[i] = self.attempts.get(i, 0) + 1
        threading.Thread(target=self._read, args=(name, proc), daemon=True).start()

    def _read(self, name: str, proc: subprocess.Popen) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            self.out(f"[{name}] {line.rstrip()}")
            if line.startswith("all ") and " modules up" in line:
                with self.cond:
                    self.up.add(name)
                    self.cond.notify_all()

    def _wait(self, names: set[str], timeout_s: float) -> None:
        end = time.monotonic() + timeout_s
        with self.cond:
            while not names <= self.up:
                for i, p in list(self.by_index.items()):
                    if p.poll() is not None and self.names[i] not in self.up and self.attempts[i] < self.max_attempts:
                        self.procs.remove(p)
                        self.out(f"[{self.names[i]}] launch exited before the robot was up: starting it again")
                        self._start_one(i)
                dead = [p for i, p in self.by_index.items() if p.poll() is not None and self.names[i] not in self.up
                        and self.attempts[i] >= self.max_attempts] + (
                    [self.hub] if self.hub is not None and self.hub.poll() is not None else [])
                if dead or time.monotonic() > end:
                    raise FleetError(f"robots not up: {sorted(names - self.up)}"
                                     + (" (a launch exited)" if dead else ""))
                self.cond.wait(0.5)

    def stop(self) -> None:
        if self.hub is not None:
            self.procs.insert(0, self.hub)
            self.hub = None
        for p in reversed(self.procs):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in reversed(self.procs):
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)


def describe_exit(code: int) -> str:
    """A launch's exit status in words: ``killed by SIGKILL`` for -9, ``exited 1`` otherwise."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exited {code}"


@dataclass
class FleetWatch:
    """What the running fleet says when a robot's launch ends: one robot's death never stops the others (their
    RALs see its liveliness go and re-allocate what it held, ral/fleet_protocol.py); the fleet ends only when
    every robot is down or the operator stops it."""

    names: tuple[str, ...]
    run_dir: Path = Path("run/fleet")
    dead: dict[str, int] = field(default_factory=dict)
    """Robot → its launch's exit status, for each robot seen down."""
    hub_down: bool = False

    def update(self, exits: dict[str, int | None], hub_exit: int | None) -> list[str]:
        """The launches' exit statuses now (None: running) → the lines to print about what changed."""
        lines = []
        for name in self.names:
            code = exits.get(name)
            if code is None or name in self.dead:
                continue
            self.dead[name] = code
            alive = [n for n in self.names if n not in self.dead]
            if alive:
                logs = self.run_dir / name / "logs"
                lines.append(f"fleet: robot {name} is down ({describe_exit(code)}; logs in {logs}): "
                             f"{len(alive)} of {len(self.names)} robots fly on ({', '.join(alive)}); the fleet "
                             f"re-allocates the targets {name} had not reached")
            else:
                lines.append(f"fleet: robot {name} is down ({describe_exit(code)}): no robot is left")
        if hub_exit is not None and not self.hub_down:
            self.hub_down = True
            lines.append(f"fleet: the hub router is down ({describe_exit(hub_exit)}): ground stations on it and the "
                         "mesh between the robots are lost; each robot flies on on its own (its own link failsafe)")
        return lines

    @property
    def all_down(self) -> bool:
        return len(self.dead) == len(self.names)


def station_lines(fleet: Fleet) -> list[str]:
    """For a secured fleet: where each ground station's pair is and the command that connects it to the hub."""
    if fleet.pki is None:
        return []
    lines = []
    for gcs in fleet.spec.gcs:
        ca, cert, key = fleet.pki.station(gcs)
        lines.append(f"fleet: ground station {gcs}: cromat gcs --connect {fleet.hub_endpoint} --ca {ca} "
                     f"--cert {cert} --key {key} robots")
    lines.append(f"fleet: identities from the fleet CA {fleet.pki.ca} (keep ca.key off the robots); the hub "
                 f"router ({fleet.spec.hub}): policy {fleet.pki.hub_config}, refusals in {fleet.hub_log}")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="cromat fleet", description=__doc__.splitlines()[0])
    ap.add_argument("fleet", help="fleet manifest (.toml), e.g. bbcs_conf/fleet10_sim.toml")
    ap.add_argument("--run-dir", default="run/fleet", help="where each robot's manifest, .conf and logs go")
    ap.add_argument("--check", action="store_true", help="write and check every robot's manifest, start nothing")
    args = ap.parse_args(argv)
    try:
        spec = load_fleet(Path(args.fleet))
        fleet = Fleet(spec, Path(args.run_dir).resolve(), out=print_line)
    except (FleetError, ManifestError) as exc:
        print(f"cromat fleet: {exc}", file=sys.stderr)
        return 1
    if args.check:
        print(f"{args.fleet}: ok ({spec.total} robots: {', '.join(fleet.names)})")
        for line in station_lines(fleet):
            print(line)
        return 0
    stop = threading.Event()
    forward_stop_signals(lambda _signum: stop.set())  # never a lock in a signal handler (bbcs.stop_signals)
    try:
        fleet.start()
        print_line(f"fleet: all {spec.total} robots up, meshed on {fleet.hub_endpoint} "
                   f"({' '.join(f'{n}={p}' for n, p in zip(fleet.names, fleet.ports, strict=True))})")
        for line in station_lines(fleet):
            print_line(line)
        watch = FleetWatch(tuple(fleet.names), fleet.run_dir)
        while not stop.is_set():
            exits = {fleet.names[i]: p.poll() for i, p in fleet.by_index.items()}
            for line in watch.update(exits, fleet.hub.poll() if fleet.hub is not None else None):
                print_line(line)
            if watch.all_down:
                return 1
            stop.wait(0.5)
        return 0
    except FleetError as exc:
        print(f"cromat fleet: {exc}", file=sys.stderr)
        return 1
    finally:
        fleet.stop()
        print_line("fleet stopped")


if __name__ == "__main__":
    raise SystemExit(main())
