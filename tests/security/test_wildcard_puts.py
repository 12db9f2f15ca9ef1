"""Issue 32 item 6: a put on a key expression with wildcards gets past no deny rule into an input that only one
writer may feed.

Zenoh admits a put whose key expression an allow rule includes and a deny rule does not: the dsp identity's
``cromat/uav1/dsp/*`` covers every sender's command key and pan & tilt's ``cromat/uav1/pan_tilt/*`` its own
CONTROL_ENTRADA, and the router delivers such a put to every subscriber it intersects. The receiving module takes
only puts on the exact key of those inputs (``bbcs/ingress.py``). Against a real robot router with the generated
policy and certificates from ``cromat certs``, with the real DSP process and simulator and the real pan & tilt
module; judged at the DSP simulator's record and pan & tilt's route acknowledgements, with each input's legitimate
writer shown to get through afterwards (so the input was live when the wildcard was refused).
"""

from __future__ import annotations

import json
import os
import select
import subprocess
import threading
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgspec
import pytest
import zenoh

from bbcs.contracts import dsp as bus
from bbcs.contracts import dsp as p
from bbcs.contracts.errors import ErrorReport
from bbcs.contracts.pan_tilt import ControlEntradaPT
from bbcs.errors import BusErrorCode
from bbcs.ingress import ExactKeyGuard
from bbcs.routing import RouteAck
from bbcs.session import SessionConfig, TlsConfig, open_session
from bbcs.testing import Processes, free_port, wait_port, wait_until
from cromat import certs
from modules.dsp.sim.record import read_record

ROBOT = "uav1"
R = f"cromat/{ROBOT}"
ROOT = Path(__file__).resolve().parents[2]
MODULES = ["dsp", "pan_tilt", "path_follower", "vision"]


def test_the_guard_passes_the_exact_key_and_reports_refusals_once_a_window() -> None:
    now = [0.0]
    reports: list[tuple[int, str]] = []
    guard = ExactKeyGuard("a/b/c", lambda n, k: reports.append((n, k)), window_s=1.0, clock=lambda: now[0])
    assert guard.admits("a/b/c")
    assert [guard.admits("a/b/*") for _ in range(1000)] == [False] * 1000
    assert reports == [(1, "a/b/*")] and guard.refused == 1000  # one report, not a thousand
    now[0] = 1.5
    assert not guard.admits("a/**")
    assert reports == [(1, "a/b/*"), (1000, "a/**")]  # the count since the last report
    assert guard.admits("a/b/c") and guard.refused == 1001


@dataclass
class Rig:
    port: int
    pki: Path
    tmp: Path

    def config(self, name: str) -> SessionConfig:
        folder = self.pki.with_name(self.pki.name + "-ground") if name == "gcs" else self.pki  # never on the robot
        tls = TlsConfig(root_ca=str(folder / "ca.pem"), cert=str(folder / f"{name}.pem"),
                        key=str(folder / f"{name}.key"))
        return SessionConfig(connect=[f"tls/localhost:{self.port}"], tls=tls)


SHIPPED_ROUTER_NICE: int | None = tomllib.loads((ROOT / "bbcs_conf" / "uav1_secure.toml").read_text())["bus"]["nice"]


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    tmp = tmp_path_factory.mktemp("wildcard")
    port = free_port()
    pki, cfg = tmp / "robot", tmp / "router.json5"
    assert certs.main([str(pki), "--gcs", "gcs", "--modules", ",".join(MODULES), "--robot", ROBOT,
                       "--acl", str(cfg), "--listen", f"tls/127.0.0.1:{port}"]) == 0
    procs = Processes()
    try:
        # at the shipped secure manifest's router priority (its `[bus] nice`), as the Module Manager starts it
        procs.start(["-m", "bbcs.router", "--config", str(cfg), "--listen", f"tls/127.0.0.1:{port}"],
                    stdout=subprocess.DEVNULL, preexec_fn=lambda: set_nice(SHIPPED_ROUTER_NICE))
        wait_port(port)
        yield Rig(port, pki, tmp)
    finally:
        procs.stop_all()


class Inbox:
    def __init__(self, session: zenoh.Session, *key_exprs: str) -> None:
        self.got: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()
        self.subs = [session.declare_subscriber(k, self._on) for k in key_exprs]

    def _on(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.got.append((str(sample.key_expr), sample.payload.to_bytes()))

    def values(self, key: str) -> list[bytes]:
        with self.lock:
            return [v for k, v in self.got if k == key]

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()


def _codes(inbox: Inbox, module: str) -> list[int]:
    return [msgspec.msgpack.decode(v, type=ErrorReport).code for v in inbox.values(f"{R}/{module}/error")]


def set_nice(nice: int | None) -> None:
    """In a child before it runs: a manifest's ``nice``, set as the Module Manager sets it
    (module_manager/process.py: a refusal leaves the inherited one)."""
    if nice is not None:
        try:
            os.setpriority(os.PRIO_PROCESS, 0, nice)
        except PermissionError:
            pass


def _start(procs: Processes, rig: Rig, module: str, *args: str, nice: int | None = None) -> None:
    """The module's process on the rig's bus; ``nice``: its manifest's scheduling priority (:func:`set_nice`)."""
    procs.start(["-m", f"modules.{module}", "--robot", ROBOT, "--bus",
                 msgspec.json.encode(rig.config(module)).decode(), *args], stderr=subprocess.DEVNULL,
                preexec_fn=lambda: set_nice(nice))


def test_a_wildcard_put_by_the_dsp_identity_reaches_no_aircraft(rig: Rig, tmp_path: Path) -> None:
    record = tmp_path / "dsp.jsonl"
    procs = Processes()
    sessions: list[zenoh.Session] = []
    try:
        sim = procs.start(["-m", "modules.dsp.sim", "--pty", "--record", str(record)], stdout=subprocess.PIPE,
                          text=True)
        assert select.select([sim.stdout], [], [], 15.0)[0], "the simulator printed nothing"
        _start(procs, rig, "dsp", "--conf", str(ROOT / "bbcs_conf" / "uav1.conf"), "--param",
               f"port={sim.stdout.readline().strip()}")
        gcs = open_session(rig.config("gcs"))
        sessions.append(gcs)
        inbox = Inbox(gcs, f"{R}/dsp/link", f"{R}/dsp/error")
        wait_until(lambda: inbox.values(f"{R}/dsp/link"), 60, "the DSP process started up")
        startup = len(read_record(record))
        dsp = open_session(rig.config("dsp"))  # whoever holds the dsp identity (its rule: cromat/uav1/dsp/*)
        owner = open_session(rig.config("path_follower"))
        sessions += [dsp, owner]
        forged = msgspec.msgpack.encode(bus.DspCommands(sender="path_follower", commands=[p.SetMode(mode=p.Mode(4))]))
        for _ in range(3):
            dsp.put(f"{R}/dsp/*", forged)
        wait_until(lambda: BusErrorCode.KEY_REFUSED in _codes(inbox, "dsp") or len(read_record(record)) > startup,
                   30, "the wildcard put refused or at the simulator")
        owner.put(f"{R}/dsp/{bus.commands_slot('path_follower')}",
                  msgspec.msgpack.encode(bus.DspCommands(sender="path_follower", commands=[p.Ping()])))
        wait_until(lambda: len(read_record(record)) > startup, 30, "the path follower's PING at the simulator")
        assert [c["name"] for c in read_record(record)[startup:]] == ["PING"], "the wildcard put reached the DSP"
        assert 1 <= _codes(inbox, "dsp").count(BusErrorCode.KEY_REFUSED) <= 2  # counted, not one report per datum
        inbox.close()
    finally:
        for s in sessions:
            s.close()
        procs.stop_all()


def test_a_wildcard_put_by_pan_tilt_does_not_reroute_its_inputs(rig: Rig, tmp_path: Path) -> None:
    """``cromat/uav1/pan_tilt/*`` from the module's own identity carried a CONTROL_ENTRADA that re-routed its
    inputs until the route audit repaired it; now the module drops it (KEY_REFUSED) and acknowledges no such route,
    while the manager's CONTROL_ENTRADA on the exact key is applied."""
    table = tmp_path / "slots.json"
    table.write_text(json.dumps({"robot": ROBOT, "slots": {
        "10": {"module": "ral", "slot": "pt_datos", "type": "bbcs.contracts.pan_tilt:DatosPT"},
        "20": {"module": "vision", "slot": "target", "type": "bbcs.contracts.pan_tilt:DatosPT"}}}))
    procs = Processes()
    sessions: list[zenoh.Session] = []
    try:
        gcs = open_session(rig.config("gcs"))
        sessions.append(gcs)
        inbox = Inbox(gcs, f"{R}/pan_tilt/@route", f"{R}/pan_tilt/error")

        def routes() -> list[dict[str, int]]:
            return [msgspec.msgpack.decode(v, type=RouteAck).routes for v in inbox.values(f"{R}/pan_tilt/@route")]

        _start(procs, rig, "pan_tilt", "--slot-table", str(table), "--route", "datos=10")
        wait_until(lambda: routes(), 60, "pan & tilt's first route acknowledgement")
        assert routes()[-1]["datos"] == 10
        attacker = open_session(rig.config("pan_tilt"))  # the module's own identity: its rule cromat/uav1/pan_tilt/*
        manager = open_session(rig.config("manager"))
        sessions += [attacker, manager]
        forged = msgspec.msgpack.encode(ControlEntradaPT(slot_entrada_datos=20))
        attacker.put(f"{R}/pan_tilt/*", forged)
        wait_until(lambda: BusErrorCode.KEY_REFUSED in _codes(inbox, "pan_tilt") or len(routes()) >= 2, 30,
                   "the wildcard put refused or acknowledged")
        manager.put(f"{R}/pan_tilt/control_entrada", msgspec.msgpack.encode(
            ControlEntradaPT(slot_entrada_datos=10, slot_entrada_control_modos=-1)))
        wait_until(lambda: len(routes()) >= 2, 30, "the manager's route acknowledged")
        assert all(r["datos"] == 10 for r in routes()), f"the wildcard put re-routed pan & tilt: {routes()}"
        assert BusErrorCode.KEY_REFUSED in _codes(inbox, "pan_tilt")
        inbox.close()
    finally:
        for s in sessions:
            s.close()
        procs.stop_all()
