"""The security matrix (issue 12) against a real robot router process with mTLS and the generated policy.

Certificates are made at test time in tmp_path (``cromat certs``), with a second CA and an expired certificate.
Every case is checked by its effect: what a legitimate observer received, what a server was asked, what reached
the DSP simulator's record. Each refused case has its legitimate twin accepted, so a dead router or a typo in a
key cannot make a refusal test pass.

Marker technique: Zenoh keeps one link's messages in order through the router, so after an attempt that must be
dropped the same session publishes a marker on a key it owns; once the observer has the marker, anything the
attempt had let through would have arrived before it.
"""

from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgspec
import pytest
import zenoh
import zenoh.ext

from bbcs import acl
from bbcs.errors import SessionError
from bbcs.session import SessionConfig, TlsConfig, open_session
from bbcs.testing import Processes, free_port, put_until_heard, wait_port, wait_until
from cromat import certs
from modules.dsp.sim.record import read_record

ROBOT = "uav1"
MODULES = ["dsp", "pan_tilt", "path_follower", "vision", "trajectory"]
R = f"cromat/{ROBOT}"


@dataclass
class Rig:
    port: int
    pki: Path
    other: Path

    def config(self, name: str | None, pki: Path | None = None, timeout_s: float = 10.0) -> SessionConfig:
        pki = pki or self.pki
        if name == "gcs":  # ground-station pairs live in the ground folder, never on the robot
            pki = pki.with_name(pki.name + "-ground")
        tls = TlsConfig(root_ca=str(pki / "ca.pem"), cert=str(pki / f"{name}.pem") if name else None,
                        key=str(pki / f"{name}.key") if name else None, mtls=name is not None)
        return SessionConfig(connect=[f"tls/localhost:{self.port}"], tls=tls, connect_timeout_s=timeout_s)


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    tmp = tmp_path_factory.mktemp("matrix")
    port = free_port()
    pki, other, cfg = tmp / "robot", tmp / "other", tmp / "router.json5"
    assert certs.main([str(pki), "--gcs", "gcs", "--modules", ",".join(MODULES), "--robot", ROBOT,
                       "--acl", str(cfg), "--listen", f"tls/127.0.0.1:{port}"]) == 0
    certs.make_leaf(pki, "expired", days=-1, ca_dir=tmp / "robot-ca")  # notAfter yesterday, the robot's own CA
    assert certs.main([str(other), "--ca-name", "intruder-ca", "--gcs", "gcs", "--no-local"]) == 0
    procs = Processes()
    try:
        procs.start(["-m", "bbcs.router", "--config", str(cfg), "--listen", f"tls/127.0.0.1:{port}"],
                    stdout=subprocess.DEVNULL)
        wait_port(port)
        yield Rig(port, pki, other)
    finally:
        procs.stop_all()


class Sessions:
    """Sessions by identity, all closed at the end."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        self.opened: dict[str, zenoh.Session] = {}

    def __call__(self, name: str) -> zenoh.Session:
        if name not in self.opened:
            self.opened[name] = open_session(self.rig.config(name))
        return self.opened[name]

    def close(self) -> None:
        for s in self.opened.values():
            s.close()


@pytest.fixture
def who(rig: Rig) -> Iterator[Sessions]:
    sessions = Sessions(rig)
    try:
        yield sessions
    finally:
        sessions.close()


class Observer:
    """A subscriber (of a legitimate reader) that records every payload on ``key``."""

    def __init__(self, session: zenoh.Session, *keys: str) -> None:
        self.got: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()
        self.subs = [session.declare_subscriber(k, self._on) for k in keys]

    def _on(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.got.append((str(sample.key_expr), sample.payload.to_bytes()))

    def values(self, key: str) -> list[bytes]:
        with self.lock:
            return [v for k, v in self.got if k == key]

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()


def attempt_then_marker(who: Sessions, attacker: str, key: str, observer: Observer) -> None:
    """``attacker`` puts b"forged" on ``key``, then a marker on its own heartbeat key; waits for the marker.

    Before the attack, a b"ready" marker until the observer has it (``put_until_heard``: a CI run timed out on a
    marker a just-opened session dropped); after it, the first marker heard follows the forged put."""
    s = who(attacker)
    marker = f"{R}/{attacker}/@heartbeat" if attacker in (*MODULES, "ral") else "cromat/@gcs/gcs/marker"

    def heard(what: bytes) -> None:
        put_until_heard(lambda: s.put(marker, what), lambda: what in observer.values(marker),
                        f"{attacker}'s marker {what!r}")

    heard(b"ready")
    s.put(key, b"forged")
    heard(b"marker")


# --- TLS: refused at connect --------------------------------------------------------------------------------

@pytest.mark.parametrize("case", ["no certificate", "another CA", "expired"])
def test_tls_refusals(rig: Rig, case: str) -> None:
    cfg = {"no certificate": lambda: rig.config(None, timeout_s=3.0),
           "another CA": lambda: rig.config("gcs", rig.other, timeout_s=3.0),
           "expired": lambda: rig.config("expired", timeout_s=3.0)}[case]()
    with pytest.raises(SessionError):
        open_session(cfg).close()


def test_legitimate_identity_connects(rig: Rig) -> None:
    open_session(rig.config("gcs")).close()


# --- plain writes: only the owner ------------------------------------------------------------------------

# (key, attacker, owner): every kind of slot, and who may not write it
WRITES = [
    (f"{R}/pan_tilt/state_out", "vision", "pan_tilt"),  # a module's output slot, another module
    (f"{R}/pan_tilt/state_out", "gcs", "pan_tilt"),  # ... the GCS identity writing a module slot directly
    (f"{R}/pan_tilt/control_entrada", "pan_tilt", "manager"),  # CONTROL_ENTRADA: not even its module
    (f"{R}/pan_tilt/control_entrada", "vision", "manager"),
    (f"{R}/manager/pan_tilt_mode", "vision", "manager"),  # a mode slot
    (f"{R}/manager/pan_tilt_mode", "gcs", "manager"),
    (f"{R}/@ral/state", "vision", "ral"),  # a GRI key
    (f"{R}/@ral/state", "gcs", "ral"),
    (f"{R}/dsp/commands", "vision", None),  # the old shared DSP mailbox: nobody
    (f"{R}/dsp/commands", "path_follower", None),
    (f"{R}/dsp/commands_path_follower", "vision", "path_follower"),  # another sender's DSP command key
    (f"{R}/dsp/commands_path_follower", "pan_tilt", "path_follower"),
    (f"{R}/dsp/commands_pan_tilt", "gcs", "pan_tilt"),
    (f"{R}/dsp/commands_path_follower", "dsp", "path_follower"),  # issue 32 item 5: the DSP's own rule dsp/* ...
    (f"{R}/dsp/commands_pan_tilt", "dsp", "pan_tilt"),  # ... covers no sender's key
    (f"{R}/dsp/commands", "dsp", None),  # ... nor the old mailbox
    (f"{R}/trajectory/request", "vision", "ral"),  # a request the RAL makes of a module, on the module's key
    (f"{R}/trajectory/request", "gcs", "ral"),
    (f"{R}/trajectory/request", "path_follower", "trajectory"),  # ... which the module itself may also write
    (f"{R}/path_follower/refs", "pan_tilt", "ral"),  # a bridge task's references
    (f"{R}/pan_tilt/@route", "vision", "pan_tilt"),  # a forged RouteAck
    (f"{R}/@ral/@schema", "vision", "ral"),  # a forged GRI schema
    ("cromat/@fleet/task/t1", "vision", "gcs"),  # a fleet task (docs/fleet.md): the ground stations' to post
    ("cromat/@fleet/task/t1", "ral", "gcs"),
]


def observer_for(attacker: str, owner: str | None) -> str:
    """A legitimate reader that is neither side (a session's own puts reach its own subscribers locally)."""
    return next(n for n in ("ral", "gcs", "dsp") if n not in (attacker, owner))


@pytest.mark.parametrize(("key", "attacker", "owner"), WRITES, ids=[f"{a}->{k.split('/', 2)[2]}" for k, a, _ in WRITES])
def test_only_the_owner_writes(who: Sessions, key: str, attacker: str, owner: str | None) -> None:
    observer = Observer(who(observer_for(attacker, owner)), key, f"{R}/*/@heartbeat", "cromat/@gcs/**")
    try:
        attempt_then_marker(who, attacker, key, observer)
        assert observer.values(key) == [], f"{attacker}'s put on {key} got through"
        if owner is not None:
            who(owner).put(key, b"legit")
            wait_until(lambda: observer.values(key) == [b"legit"], 20, f"{owner}'s own put on {key}")
    finally:
        observer.close()


# --- history injection: answering late-joiner queries is writing ---------------------------------------

HISTORY = [
    (f"{R}/pan_tilt/mode_out", "gcs", "pan_tilt"),  # state slot, the GCS identity
    (f"{R}/path_follower/errors", "pan_tilt", "path_follower"),  # stream slot, another module
    (f"{R}/pan_tilt/control_entrada", "vision", "manager"),  # CONTROL_ENTRADA, another module
    (f"{R}/pan_tilt/control_entrada", "pan_tilt", "manager"),  # ... its own module
    (f"{R}/manager/pan_tilt_mode", "pan_tilt", "manager"),  # mode slot
    (f"{R}/@ral/state", "vision", "ral"),  # GRI state (the fake "pos 0 0 999 m mode SPOOFED")
    (f"{R}/dsp/commands_path_follower", "pan_tilt", "path_follower"),  # a DSP command key
    (f"{R}/trajectory/request", "vision", "ral"),  # a request the RAL makes on a module's key
    (f"{R}/manager/pan_tilt_mode", "gcs", "manager"),  # the "GCS changed the pan & tilt mode"
    (f"{R}/manager/path_follower_mode", "pan_tilt", "manager"),  # ... "pan_tilt made the follower Abort"
    (f"{R}/pan_tilt/@route", "vision", "pan_tilt"),  # a RouteAck: what the manager's drift audit believes
]


class LateHistory:
    """A late-joining advanced subscriber on ``key``: what it gets as history."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.got: list[bytes] = []
        self.lock = threading.Lock()
        self.sub = zenoh.ext.declare_advanced_subscriber(
            session, key, self._on, history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1))

    def _on(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.got.append(sample.payload.to_bytes())

    def values(self) -> list[bytes]:
        with self.lock:
            return list(self.got)

    def close(self) -> None:
        self.sub.undeclare()


def late_history(session: zenoh.Session, key: str) -> list[bytes]:
    """What a late-joining advanced subscriber gets as history on ``key``, once it got any."""
    late = LateHistory(session, key)
    try:
        wait_until(lambda: bool(late.values()), 20, f"history on {key}")
        return late.values()
    finally:
        late.close()


def advanced_publisher(session: zenoh.Session, key: str) -> object:
    return zenoh.ext.declare_advanced_publisher(
        session, key, cache=zenoh.ext.CacheConfig(1),
        sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=0.5), publisher_detection=True)


FORGED_WINDOW_S = 2.0
"""The policy must have kept a forged value out: a wrongly admitted one is given this long to arrive."""


def one_key_each(cases: list[tuple[str, str, str]]) -> list[list[tuple[str, str, str]]]:
    """``cases`` in batches with each key at most once, so no case's reader can see another case's forgery."""
    batches: list[list[tuple[str, str, str]]] = []
    for case in cases:
        batch = next((b for b in batches if all(other[0] != case[0] for other in b)), None)
        if batch is None:
            batches.append(batch := [])
        batch.append(case)
    return batches


@pytest.fixture(scope="module")
def forged_history(rig: Rig) -> dict[tuple[str, str, str], list[bytes]]:
    """What each HISTORY case's reader got as history after its attacker's forgery. The forgeries of a batch (one
    per key) are made side by side, so their cases share one ``FORGED_WINDOW_S`` instead of one each: in each,
    the attacker's advanced publisher puts b"forged", then the reader's late-joining subscriber waits the window;
    every forged publisher is gone before any test's owner publishes."""
    sessions = Sessions(rig)
    got: dict[tuple[str, str, str], list[bytes]] = {}
    try:
        for batch in one_key_each(HISTORY):
            forged = [advanced_publisher(sessions(attacker), key) for key, attacker, _ in batch]
            late: list[LateHistory] = []
            try:
                for pub in forged:
                    pub.put(b"forged")  # type: ignore[attr-defined]
                late = [LateHistory(sessions(observer_for(attacker, owner)), key) for key, attacker, owner in batch]
                threading.Event().wait(FORGED_WINDOW_S)
                got.update((case, sub.values()) for case, sub in zip(batch, late, strict=True))
            finally:
                for sub in late:
                    sub.close()
                for pub in forged:
                    pub.undeclare()  # type: ignore[attr-defined]
    finally:
        sessions.close()
    return got


@pytest.mark.parametrize(("key", "attacker", "owner"), HISTORY,
                         ids=[f"{a}->{k.split('/', 2)[2]}" for k, a, _ in HISTORY])
def test_history_injection_is_refused_and_owner_history_served(
        who: Sessions, forged_history: dict[tuple[str, str, str], list[bytes]], key: str, attacker: str,
        owner: str) -> None:
    reader = observer_for(attacker, owner)
    assert forged_history[(key, attacker, owner)] == []
    legit = advanced_publisher(who(owner), key)
    try:
        legit.put(b"legit")  # type: ignore[attr-defined]
        assert late_history(who(reader), key) == [b"legit"]
    finally:
        legit.undeclare()  # type: ignore[attr-defined]


# --- queries: tasks and route swaps are the GCS's; a query nobody may make never reaches the server ----------

@pytest.mark.parametrize(("key", "server"), [(f"{R}/@ral/task", "ral"), (f"{R}/@manager/route", "manager"),
                                             (f"{R}/@ral/world_request", "ral"), (f"{R}/@ral/sync", "ral")])
def test_module_identity_cannot_command_the_gcs_tasks(who: Sessions, key: str, server: str) -> None:
    asked: list[str] = []

    def on_query(query: zenoh.Query) -> None:
        asked.append(str(query.selector))
        query.reply(query.key_expr, b"ok")

    q = who(server).declare_queryable(key, on_query)
    try:
        for name in ("pan_tilt", "vision", "dsp"):
            replies = list(who(name).get(key, timeout=2.0))
            assert not [r for r in replies if r.ok is not None], f"{name} got an answer from {key}"
        assert asked == []  # by effect: the server was never asked
        replies = list(who("gcs").get(key, timeout=10.0))
        assert [r.ok.payload.to_bytes() for r in replies if r.ok is not None] == [b"ok"]
        assert len(asked) == 1
    finally:
        q.undeclare()


ANSWERS = [
    (f"{R}/@ral/state", "vision", "ral"),  # a GRI key (published, never queried: the owner's twin is pub/sub)
    (f"{R}/@ral/@schema", "vision", "ral"),  # the GRI's schemas (``*`` never matched the ``@ral`` chunk)
    (f"{R}/@manager/@schema", "pan_tilt", "manager"),  # the MRI's schemas
    (f"{R}/@ral/@schema", "gcs", "ral"),
    (f"{R}/@ral/clock", "vision", "ral"),  # fleet time: a forged clock would skew every robot's start
    (f"{R}/@ral/world_model", "pan_tilt", "ral"),  # the shared world a late joiner copies
]


@pytest.mark.parametrize(("key", "attacker", "owner"), ANSWERS,
                         ids=[f"{a}->{k.split('/', 2)[2]}" for k, a, _ in ANSWERS])
def test_only_the_owner_answers_a_get_and_the_gcs_reads_it(who: Sessions, key: str, attacker: str,
                                                            owner: str) -> None:
    """A module that declares a queryable on a GRI/MRI key (schemas included) never answers anyone; the
    owner's queryable answers the GCS identity and a module identity (schemas are read-only, for everyone)."""
    asked: list[str] = []

    def serve(answer: bytes):  # noqa: ANN202
        def on_query(query: zenoh.Query) -> None:
            asked.append(answer.decode())
            query.reply(query.key_expr, answer)
        return on_query

    readers = [n for n in ("gcs", "dsp") if n != attacker]  # never the attacker: its own queryable is local
    q = who(attacker).declare_queryable(key, serve(b"SPOOFED"))
    try:
        for reader in readers:
            replies = list(who(reader).get(key, timeout=2.0))
            assert [r.ok.payload.to_bytes() for r in replies if r.ok is not None] == []
        assert asked == []  # the forged queryable was never even asked
    finally:
        q.undeclare()
    if not key.endswith(("/@schema", "/clock", "/world_model")):
        return
    q = who(owner).declare_queryable(key, serve(b"legit"))
    try:
        for reader in readers:
            got: list[bytes] = []

            def fetch(reader: str = reader, got: list[bytes] = got) -> bool:
                got[:] = [r.ok.payload.to_bytes() for r in who(reader).get(key, timeout=5.0) if r.ok is not None]
                return bool(got)
            wait_until(fetch, 30, f"{reader} reads {key} from its owner")
            assert got == [b"legit"]
    finally:
        q.undeclare()


def test_everyone_reads(who: Sessions) -> None:
    key = f"{R}/pan_tilt/state_out"
    observers = [Observer(who(n), key) for n in ("gcs", "vision", "dsp", "manager")]
    try:
        who("pan_tilt").put(key, msgspec.msgpack.encode({"v": 1}))
        for o in observers:
            wait_until(lambda o=o: bool(o.values(key)), 20, "every identity reads the slot")
    finally:
        for o in observers:
            o.close()


# --- the DSP: only the module that owns a command class gets it to the aircraft (the simulator's record) ---

def _batch(sender: str, *commands: object) -> bytes:
    from bbcs.contracts import dsp as bus

    return msgspec.msgpack.encode(bus.DspCommands(sender=sender, commands=list(commands), batch_id=7))


def test_dsp_commands_reach_the_simulator_only_from_their_owner(rig: Rig, who: Sessions, tmp_path: Path) -> None:
    import select

    from bbcs.contracts import dsp as p

    record = tmp_path / "dsp.jsonl"
    conf = Path(__file__).resolve().parents[2] / "bbcs_conf" / "uav1.conf"
    procs = Processes()
    try:
        sim = procs.start(["-m", "modules.dsp.sim", "--pty", "--record", str(record)], stdout=subprocess.PIPE,
                          text=True)
        assert select.select([sim.stdout], [], [], 15.0)[0], "the simulator printed nothing"
        pty = sim.stdout.readline().strip()
        procs.start(["-m", "modules.dsp", "--robot", ROBOT, "--bus", msgspec.json.encode(rig.config("dsp")).decode(),
                     "--conf", str(conf), "--param", f"port={pty}"], stderr=subprocess.DEVNULL)
        observer = Observer(who("gcs"), f"{R}/dsp/link", f"{R}/dsp/errors", f"{R}/*/@heartbeat")
        try:
            wait_until(lambda: observer.values(f"{R}/dsp/link"), 60, "the DSP process started up")

            def names() -> list[str]:
                return [c["name"] for c in read_record(record)]

            startup = len(names())
            # refused: the vision identity on the path follower's key (router), the shared mailbox (router),
            # the pan & tilt identity sending a class it does not own on its own key (DSP, reported)
            who("vision").put(f"{R}/dsp/commands_path_follower", _batch("path_follower", p.Abort()))
            who("vision").put(f"{R}/dsp/commands", _batch("path_follower", p.Abort()))
            # the dsp identity itself (issue 32 item 5): its rule dsp/* no longer covers the senders' keys
            who("dsp").put(f"{R}/dsp/commands_path_follower", _batch("path_follower", p.SetMode(mode=p.Mode(4))))
            who("dsp").put(f"{R}/dsp/commands", _batch("nobody", p.SetMode(mode=p.Mode(4))))
            who("pan_tilt").put(f"{R}/dsp/commands_pan_tilt", _batch("path_follower", p.SetMode(mode=p.Mode.LANDING)))
            wait_until(lambda: any(b"NOT_OWNER" in v or b"does not own" in v
                                   for v in observer.values(f"{R}/dsp/errors")), 30, "the DSP's NOT_OWNER report")
            # accepted: each owner's own class on its own key; the record then shows exactly these (the router
            # passes one put on pan & tilt's key per 1/SET_POINT_RATES_HZ: this one comes after its refused one)
            time.sleep(2 / acl.SET_POINT_RATES_HZ["pan_tilt"])
            who("pan_tilt").put(f"{R}/dsp/commands_pan_tilt", _batch("x", p.SetPanTiltAngles(pan_deg=10, tilt_deg=5)))
            wait_until(lambda: "SET_PT_ANGLES" in names(), 30, "the pan & tilt command at the simulator")
            who("path_follower").put(f"{R}/dsp/commands_path_follower", _batch("x", p.Abort()))
            wait_until(lambda: "ABORT" in names(), 30, "the path follower's ABORT at the simulator")
            assert names()[startup:] == ["SET_PT_ANGLES", "ABORT"]  # nothing refused reached the aircraft
            report = next(msgspec.msgpack.decode(v) for v in observer.values(f"{R}/dsp/errors")
                          if b"does not own" in v)
            # the key's sender, not the field's
            assert report["sender"] == "pan_tilt" and report["command"] == "SetMode"
        finally:
            observer.close()
    finally:
        procs.stop_all()
