"""``[bus] links = "peers"`` under ``[bus.tls]``: a module linked directly to another still cannot write what it does
not own, because the *receiver* enforces the robot's access policy on its ingress (module_manager/bus_links.py).

The rig is uav1_secure.toml's: the router with the generated config and policy, certificates from ``cromat certs
--manifest`` made in tmp_path, and module sessions built exactly as the manager builds them (``bus_links.module_bus``).
The attacker holds a real identity (vision's certificate) and runs a *compromised* peer: no policy of its own, linked
directly to its victim (checked: the victim is among its peers). Each case is checked by effect: what the victim's
subscriber received. The legitimate twin (the DSP identity publishing its own telemetry) is delivered, and a victim
whose session had no policy *does* receive the forgery, which proves that the forgery really travels the direct
link (the router would have dropped it) and that the receiver's policy is what stops it.

Witness and marker: a session of the victim's identity that enforces nothing (the witness) subscribes beside the
victim; the attacker writes the forgery until the witness has it (so it did travel a direct link: the router drops
it), then a marker on a key it owns, and the victim's inbox is judged once the marker has reached it. Zenoh gives no
order between the router's path and the direct one, so the witness, not a single write, is what shows the attack was
really made.
"""

from __future__ import annotations

import subprocess
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import msgspec
import pytest
import zenoh

from bbcs import keys
from bbcs.session import open_session
from bbcs.testing import Processes, free_port, wait_port, wait_until
from cromat import certs
from module_manager import bus_links, secure
from module_manager.manifest import Manifest, load_manifest

ROOT = Path(__file__).resolve().parents[2]
MANIFEST = ROOT / "bbcs_conf" / "uav1_secure.toml"
ROBOT = "uav1"
TELEMETRY = keys.slot_key(ROBOT, "dsp", "telemetry")
CONTROL = keys.slot_key(ROBOT, "pan_tilt", "control_entrada")
MARKER = keys.slot_key(ROBOT, "vision", "marker")


def secure_manifest(tmp: Path, port: int) -> Path:
    text = MANIFEST.read_text()
    for old, new in (('conf = "uav1.conf"', f'conf = "{MANIFEST.parent / "uav1.conf"}"'),
                     ('pki = "pki"', f'pki = "{tmp / "pki"}"'),
                     ('listen = ["tls/127.0.0.1:7447"]', f'listen = ["tls/127.0.0.1:{port}"]\nlinks = "peers"')):
        assert text.count(old) == 1, f"{old!r} changed in uav1_secure.toml"
        text = text.replace(old, new)
    path = tmp / "uav1_secure.toml"
    path.write_text(text)
    return path


@dataclass
class Rig:
    manifest: Manifest
    connect: list[str]
    procs: Processes
    sessions: list[zenoh.Session] = field(default_factory=list)

    def module(self, identity: str, *, policy: bool = True) -> zenoh.Session:
        """A module's session as the manager configures it; ``policy=False``: a compromised one without its ACL."""
        cfg = bus_links.module_bus(self.manifest, secure.client_bus(self.manifest, self.connect, identity),
                               bus_links.peer_access_control(self.manifest) if policy else None)
        assert cfg.mode == "peer" and cfg.listen == ["tls/127.0.0.1:0"]
        s = open_session(cfg)
        self.sessions.append(s)
        return s


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    tmp = tmp_path_factory.mktemp("peer_links")
    port = free_port()
    path = secure_manifest(tmp, port)
    assert certs.main(["--manifest", str(path)]) == 0
    manifest = load_manifest(path)
    assert bus_links.links(manifest) == "peers"
    listen = [f"tls/127.0.0.1:{port}"]
    config = secure.write_router_config(manifest, listen, tmp)
    procs = Processes()
    r = Rig(manifest, [f"tls/127.0.0.1:{port}"], procs)
    try:
        procs.start(["-m", "bbcs.router", "--config", str(config), "--listen", listen[0]], stdout=subprocess.DEVNULL)
        wait_port(port)
        yield r
    finally:
        for s in r.sessions:
            s.close()
        procs.stop_all()


class Inbox:
    """What a victim's subscribers received, by key, with a wait for the marker."""

    def __init__(self, session: zenoh.Session, *key_exprs: str) -> None:
        self.got: list[tuple[str, bytes]] = []
        self.cond = threading.Condition()
        self.subs = [session.declare_subscriber(k, self._on) for k in key_exprs]

    def _on(self, sample: zenoh.Sample) -> None:
        with self.cond:
            self.got.append((str(sample.key_expr), sample.payload.to_bytes()))
            self.cond.notify_all()

    def wait_for(self, key: str, payload: bytes, timeout_s: float = 15.0) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: (key, payload) in self.got, timeout_s)

    def values(self, key: str) -> list[bytes]:
        with self.cond:
            return [p for k, p in self.got if k == key]

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()


def linked(a: zenoh.Session, b: zenoh.Session) -> bool:
    return b.zid() in a.info.peers_zid() and a.zid() in b.info.peers_zid()


def attempt(victim: zenoh.Session, attacker: zenoh.Session, key: str, forged: bytes, tag: bytes,
            witness: zenoh.Session) -> Inbox:
    """Subscribe the victim and a witness (a session of the same identity that enforces nothing), wait for the
    direct links and the subscriptions, write ``forged`` until the witness has it, then a marker; returns the
    victim's inbox once the marker has reached it.

    Why a witness: a peer learns a subscription from two faces, the direct link and the router, and the two paths
    have no order between them. The witness receiving the forgery shows that the forgery did travel a direct link
    at that moment (the router drops it), and the marker written after that shows the victim's link has
    delivered everything written before it."""
    inbox = Inbox(victim, key, MARKER)
    seen = Inbox(witness, key)
    for peer in (victim, witness):
        wait_until(lambda p=peer: linked(p, attacker), 30, "the attacker never linked directly to the victim")
    pub = attacker.declare_publisher(key)
    marker = attacker.declare_publisher(MARKER)
    wait_until(lambda: marker.matching_status.matching, 30, "the victim's marker subscription never arrived")
    for _ in range(20):
        pub.put(forged)
        if seen.wait_for(key, forged, 1.0):
            break
    else:
        raise AssertionError("the forgery never reached the witness over its direct link: the attack was not made")
    marker.put(tag)
    assert inbox.wait_for(MARKER, tag), "the attacker's own marker never reached the victim"
    seen.close()
    pub.undeclare()
    marker.undeclare()
    return inbox


def test_compromised_module_cannot_write_a_slot_it_does_not_own_over_a_direct_link(rig: Rig) -> None:
    victim = rig.module("pan_tilt")  # reads the DSP's telemetry, owns its CONTROL_ENTRADA (the manager writes it)
    witness = rig.module("pan_tilt", policy=False)
    attacker = rig.module("vision", policy=False)
    forged = msgspec.msgpack.encode({"lat": 200.0, "mode": "SPOOFED"})
    inbox = attempt(victim, attacker, TELEMETRY, forged, b"m1", witness)
    assert inbox.values(TELEMETRY) == []
    inbox.close()
    inbox = attempt(victim, attacker, CONTROL, msgspec.msgpack.encode({"datos": 20}), b"m2", witness)
    assert inbox.values(CONTROL) == []
    inbox.close()


def test_the_owner_is_delivered_over_its_direct_link(rig: Rig) -> None:
    victim = rig.module("pan_tilt")
    owner = rig.module("dsp", policy=False)  # its own policy plays no part in what the receiver accepts
    inbox = Inbox(victim, TELEMETRY)
    wait_until(lambda: linked(victim, owner), 30, "the DSP never linked directly to pan_tilt")
    pub = owner.declare_publisher(TELEMETRY)
    wait_until(lambda: pub.matching_status.matching, 30, "pan_tilt's telemetry subscription")
    pub.put(b"real telemetry")
    assert inbox.wait_for(TELEMETRY, b"real telemetry")
    inbox.close()
    pub.undeclare()


def test_without_the_receivers_policy_the_forgery_would_arrive(rig: Rig) -> None:
    """The control case: the same attack on a victim whose session enforces nothing is delivered, so the forgery
    does travel the direct link and the router is not what stopped it above."""
    victim = rig.module("pan_tilt", policy=False)
    attacker = rig.module("vision", policy=False)
    inbox = Inbox(victim, TELEMETRY)
    wait_until(lambda: linked(victim, attacker), 30, "the attacker never linked directly to the victim")
    pub = attacker.declare_publisher(TELEMETRY)
    wait_until(lambda: pub.matching_status.matching, 30, "the victim's telemetry subscription never arrived")
    pub.put(b"forged")
    assert inbox.wait_for(TELEMETRY, b"forged"), "a forgery on a direct link to a victim without a policy was lost"
    inbox.close()
    pub.undeclare()


def test_what_the_router_forwards_reaches_a_module_enforcing_its_policy(rig: Rig) -> None:
    """The manager is a client of the router: its CONTROL_ENTRADA write reaches pan_tilt only through the router's
    link, which the module's policy must know by the CN the router's certificate really presents
    (``router-uav1``); a wrong CN there cut every peer module off from the manager and the ground stations."""
    victim = rig.module("pan_tilt")
    manager = open_session(secure.client_bus(rig.manifest, rig.connect, "manager"))
    rig.sessions.append(manager)
    inbox = Inbox(victim, CONTROL)
    pub = manager.declare_publisher(CONTROL)
    wait_until(lambda: pub.matching_status.matching, 30, "pan_tilt's CONTROL_ENTRADA subscription never reached "
               "the manager through the router")
    route = msgspec.msgpack.encode({"datos": 2})
    for _ in range(10):  # a put may cross the subscription's declaration on its way: repeat until one lands
        pub.put(route)
        if inbox.wait_for(CONTROL, route, 1.0):
            break
    assert inbox.values(CONTROL), "the manager's write through the router never reached the module's peer session"
    inbox.close()
    pub.undeclare()


def test_a_client_of_the_router_sees_a_policed_peer_modules_token(rig: Rig) -> None:
    """Supervision: the manager learns that a module is alive from its liveliness token, which a peer module
    sends to the router only once the router's interest (declared over the same link) is let in by its policy."""
    module = rig.module("telemetry")
    token = module.liveliness().declare_token(keys.alive_key(ROBOT, "telemetry"))
    manager = open_session(secure.client_bus(rig.manifest, rig.connect, "manager"))
    rig.sessions.append(manager)
    seen = threading.Event()
    sub = manager.liveliness().declare_subscriber(keys.alive_key(ROBOT, "telemetry"), lambda _s: seen.set(),
                                                  history=True)
    assert seen.wait(20), "the manager never saw the peer module's liveliness token through the router"
    sub.undeclare()
    token.undeclare()


def test_the_peer_policy_names_the_routers_certificate(rig: Rig) -> None:
    router_cn = secure.router_cn(rig.manifest)
    assert router_cn == f"router-{ROBOT}"  # cromat certs --manifest names the router by its robot
    policy = bus_links.peer_access_control(rig.manifest)
    assert policy is not None
    assert {"id": "router-link", "cert_common_names": [router_cn]} in policy["subjects"]


# --- issue 32 item 4: the router's key, read on the robot, is no master key over a direct link ----------------

def _start_peer_dsp(rig: Rig, tmp: Path) -> tuple[Path, Processes]:
    """The real DSP process as the manager starts it under ``links = "peers"`` (its peer session enforcing the
    policy), on a simulator that records what reached the aircraft."""
    import select

    record = tmp / "dsp.jsonl"
    procs = Processes()
    sim = procs.start(["-m", "modules.dsp.sim", "--pty", "--record", str(record)], stdout=subprocess.PIPE, text=True)
    assert select.select([sim.stdout], [], [], 15.0)[0], "the simulator printed nothing"
    pty = sim.stdout.readline().strip()
    bus = bus_links.module_bus(rig.manifest, secure.client_bus(rig.manifest, rig.connect, "dsp"),
                           bus_links.peer_access_control(rig.manifest))
    procs.start(["-m", "modules.dsp", "--robot", ROBOT, "--bus", msgspec.json.encode(bus).decode(),
                 "--conf", str(ROOT / "bbcs_conf" / "uav1.conf"), "--param", f"port={pty}"],
                stderr=subprocess.DEVNULL)
    return record, procs


def _router_key_session(rig: Rig) -> zenoh.Session:
    """Whoever read ``router.pem``/``router.key`` from the robot folder: a peer without any policy of its own."""
    pki = rig.manifest.pki
    assert pki is not None
    cfg = bus_links.peer_session(secure.client_bus(rig.manifest, rig.connect, secure.ROUTER), None)
    s = open_session(cfg)
    rig.sessions.append(s)
    return s


def test_the_routers_key_cannot_command_the_dsp_over_a_direct_link(rig: Rig, tmp_path: Path) -> None:
    """Issue 32 item 4: ADD_WAYPOINT and SET_MODE 4 written with the router's certificate straight to the DSP
    process reach no aircraft (the simulator's record), while the path follower's own command on its own key does;
    a policy-less witness of the DSP's identity gets the forgery, so it did travel a direct link."""
    from bbcs.contracts import dsp as bus
    from bbcs.contracts import dsp as p
    from modules.dsp.sim.record import read_record

    record, procs = _start_peer_dsp(rig, tmp_path)
    try:
        attacker = _router_key_session(rig)
        witness = rig.module("dsp", policy=False)
        owner = rig.module("path_follower")
        key = keys.slot_key(ROBOT, "dsp", bus.commands_slot("path_follower"))
        link = keys.slot_key(ROBOT, "dsp", bus.LINK_SLOT)
        seen = Inbox(witness, key, link)
        wait_until(lambda: seen.values(link), 60, "the DSP process started up")
        startup = len(read_record(record))
        forged = msgspec.msgpack.encode(bus.DspCommands(sender="path_follower", batch_id=66, commands=[
            p.AddWaypoint(lat=37.5, lon=-6.0, alt=80.0), p.SetMode(mode=p.Mode(4))]))
        pub = attacker.declare_publisher(key)
        wait_until(lambda: pub.matching_status.matching, 30, "the attacker sees the DSP's command subscription")
        for _ in range(40):
            pub.put(forged)
            if seen.wait_for(key, forged, 0.5):
                break
        else:
            raise AssertionError("the forgery never reached the witness over a direct link: the attack was not made")
        ours = {str(s.zid()) for s in rig.sessions}
        wait_until(lambda: {str(z) for z in attacker.info.peers_zid()} - ours, 30,
                   "the attacker never linked directly to the DSP process")
        for _ in range(5):  # now over the direct link to the DSP process itself
            pub.put(forged)
        real = owner.declare_publisher(key)
        wait_until(lambda: real.matching_status.matching, 30, "the path follower sees the DSP's subscription")
        real.put(msgspec.msgpack.encode(bus.DspCommands(sender="path_follower", batch_id=1, commands=[
            p.SetSpeed(speed=3.0)])))
        wait_until(lambda: "SET_SPEED" in [c["name"] for c in read_record(record)[startup:]], 30,
                   "the path follower's own command at the simulator")
        assert [c["name"] for c in read_record(record)[startup:]] == ["SET_SPEED"], "the forgery reached the DSP"
        seen.close()
        pub.undeclare()
        real.undeclare()
    finally:
        procs.stop_all()


def test_the_router_link_gets_what_the_router_forwards_and_no_module_rights(rig: Rig) -> None:
    policy = bus_links.peer_access_control(rig.manifest)
    assert policy is not None
    granted = next(p for p in policy["policies"] if p["id"] == "router-link")["rules"]
    assert "manager-write" in granted and "gcs-command" in granted
    assert not [r for r in granted if r.startswith("m-") or r.startswith("ral-")], granted
