"""Issue 33 on a secured robot (``bbcs_conf/uav1_secure.toml``: mutual TLS, the router's access policy; every
certificate made by ``cromat certs --manifest`` in tmp_path): the gateway is a ground-station identity of its own
(``mavlink``, one more name in the manifest's ``[bus.tls] gcs``), and the robot's GRI link is held only while a
MAVLink ground station is heard.

The MAVLink client is pymavlink's (independent of the gateway's code), sending a ground station's HEARTBEAT every
second as QGroundControl does. Checked by effect: the DSP simulator's record, the robot's GRI state and events as a
ground station of the test's own (the ``gcs`` identity, no link held) sees them.

- A gateway without a certificate is refused by the router (exit 3); one presenting a module's certificate (a valid
  CA, not a ground station) sees the robot but gets nothing through: no link, no task, nothing at the DSP.
- The gateway with its own certificate: the link comes up only once the client's heartbeats are heard; a take-off
  reaches the DSP; when the client goes quiet the gateway releases the link, the robot sees it lost and, after its
  ``failsafe_timeout_s``, runs its failsafe (``hold``: ABORT at the DSP), as when ``cromat gcs link`` stops.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from bbcs.contracts import gri
from bbcs.testing import free_port, wait_until
from cromat import certs

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "system"))
from mavlink_support import GatewayProcess, Mav, free_udp_port  # noqa: E402
from test_secure_launch import ROBOT, Robot, launched, secure_manifest  # noqa: E402

pytestmark = pytest.mark.timeout(300)
QUIET_S = 5.0
"""Seconds watched for something that must not happen (a task at the DSP, a link)."""


class Site:
    def __init__(self, robot: Robot, manifest: Path) -> None:
        self.robot = robot
        self.manifest = manifest
        self.ground = robot.pki.with_name("pki-ground")
        self.lock = threading.Lock()
        self.events: list[gri.GriEvent] = []
        self.states: list[gri.GriState] = []
        self.gcs = robot.client("gcs", timeout_s=10.0)  # reads; holds no link (its end would arm nothing)
        self.gcs.watch(ROBOT, self._on_state)
        self.gcs.events(ROBOT, self._on_event)

    def _on_state(self, state: gri.GriState) -> None:
        with self.lock:
            self.states = [*self.states[-20:], state]

    def _on_event(self, event: gri.GriEvent) -> None:
        with self.lock:
            self.events.append(event)

    @property
    def state(self) -> gri.GriState:
        wait_until(lambda: bool(self.states), 30, "a GRI state")
        with self.lock:
            return self.states[-1]

    def kinds(self, mark: int = 0) -> list[str]:
        with self.lock:
            return [e.kind for e in self.events[mark:]]

    def gateway(self, *tls: str, timeout_s: float = 10.0) -> tuple[GatewayProcess, int]:
        """``cromat mavlink`` on the robot's TLS endpoint with ``tls`` (the --ca/--cert/--key given) and a TCP
        server for the client; returns it and the TCP port once it serves (or has exited)."""
        tcp = free_port()
        gw = GatewayProcess("--connect", f"tls/127.0.0.1:{self.robot.launch.port}", *tls, "--name", "mavlink",
                            "--manifest", str(self.manifest), "--tcp", str(tcp), "--udp",
                            f"127.0.0.1:{free_udp_port()}", "--timeout", f"{timeout_s:g}", "-v")
        return gw, tcp

    def identity(self, folder: Path, name: str) -> tuple[str, ...]:
        return ("--ca", str(self.ground / "ca.pem"), "--cert", str(folder / f"{name}.pem"), "--key",
                str(folder / f"{name}.key"))


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Site]:
    tmp = tmp_path_factory.mktemp("mavlink-secure")
    port = free_port()
    manifest, pki = secure_manifest(tmp, port)
    text = manifest.read_text()
    assert text.count('gcs = ["gcs"]') == 1, "uav1_secure.toml's ground stations changed"
    manifest.write_text(text.replace('gcs = ["gcs"]', 'gcs = ["gcs", "mavlink"]'))
    assert certs.main(["--manifest", str(manifest)]) == 0  # the gateway's own pair, in the ground folder
    with launched(manifest, pki, tmp, port) as robot:
        s = Site(robot, manifest)
        try:
            wait_until(lambda: s.state.position is not None and s.state.home is not None, 60, "a position")
            yield s
        finally:
            s.gcs.close()


def test_the_gateways_identity_is_its_own_certificate(site: Site) -> None:
    assert {p.name for p in site.ground.iterdir()} >= {"ca.pem", "mavlink.pem", "mavlink.key"}
    assert not (site.robot.pki / "mavlink.key").exists()  # a ground station's key is never on the robot


def test_a_gateway_without_a_certificate_is_refused(site: Site) -> None:
    mark = len(site.robot.commands())
    gw, _ = site.gateway("--ca", str(site.ground / "ca.pem"), timeout_s=3.0)
    try:
        wait_until(lambda: gw.proc.poll() is not None, 30, "the gateway's exit")
    finally:
        gw.close()
    assert gw.proc.returncode == 3, gw.lines
    assert any("router" in line for line in gw.lines), gw.lines
    assert site.robot.commands()[mark:] == []


def test_a_gateway_with_a_module_certificate_gets_nothing_through(site: Site) -> None:
    """Its CA is the robot's, so it connects and reads the state (every identity does): the vehicle appears. But it
    is no ground station: its heartbeats never link the robot, its task requests are dropped by the router."""
    mark, events = len(site.robot.commands()), len(site.kinds())
    gw, tcp = site.gateway(*site.identity(site.robot.pki, "vision"), timeout_s=3.0)
    qgc = None
    try:
        gw.wait_line(f"robot {ROBOT} is MAVLink system 1", 60)
        qgc = Mav(tcp, heartbeats=True)
        qgc.wait(0, "HEARTBEAT", sysid=1, timeout_s=20)
        gw.wait_line(f"link to {ROBOT} held", 20)  # the gateway tries: the router drops its heartbeats
        at = qgc.mark()
        qgc.mav.command_long_send(1, 1, 22, 0, 0, 0, 0, float("nan"), 0, 0, float("nan"))  # NAV_TAKEOFF
        ack = qgc.wait(at, "COMMAND_ACK", lambda m: m.command == 22, 20)
        assert ack.result != 0, "a take-off ACCEPTED through a module's identity"
        time.sleep(QUIET_S)
        assert site.state.link == "no_gcs", site.state.link
        assert "link_up" not in site.kinds(events)
        assert site.robot.commands()[mark:] == []
    finally:
        if qgc is not None:
            qgc.close()
        gw.close()


def test_own_certificate_flies_and_a_quiet_ground_station_is_a_lost_link(site: Site) -> None:
    robot = site.robot
    assert site.state.link == "no_gcs" and not site.state.airborne
    gw, tcp = site.gateway(*site.identity(site.ground, "mavlink"))
    qgc = None
    try:
        gw.wait_line(f"robot {ROBOT} is MAVLink system 1", 60)
        # the vehicle is served (telemetry) before any ground station is heard, but the robot is not linked
        watcher = Mav(tcp)
        try:
            watcher.wait(0, "HEARTBEAT", sysid=1, timeout_s=20)
            time.sleep(QUIET_S)
            assert site.state.link == "no_gcs"
        finally:
            watcher.close()
        # a ground station's heartbeats: the link comes up
        events = len(site.kinds())
        qgc = Mav(tcp, heartbeats=True)
        wait_until(lambda: site.state.link == "up", 20, "the link up at the robot")
        assert "link_up" in site.kinds(events)
        # a take-off through the gateway's identity reaches the DSP (its take-off mode)
        mark, at = len(robot.commands()), qgc.mark()
        qgc.mav.command_long_send(1, 1, 22, 0, 0, 0, 0, float("nan"), 0, 0, float("nan"))
        assert qgc.wait(at, "COMMAND_ACK", lambda m: m.command == 22, 30).result == 0  # ACCEPTED
        wait_until(lambda: [c["fields"]["mode"] for c in robot.commands()[mark:] if c["name"] == "SET_MODE"] == [4],
                   20, "the take-off mode at the DSP")
        wait_until(lambda: "task_completed" in site.kinds(events), 90, "the take-off completed")
        # the ground station goes quiet (its connection stays open): link lost, then the failsafe's hold
        mark, events = len(robot.commands()), len(site.kinds())
        quiet_at = time.monotonic()
        qgc.quiet()
        gw.wait_line(f"link to {ROBOT} released", 15)
        wait_until(lambda: "link_lost" in site.kinds(events), 15, "the robot's link lost")
        wait_until(lambda: "failsafe" in site.kinds(events), 30, "the robot's failsafe")
        failsafe_after = time.monotonic() - quiet_at
        wait_until(lambda: "ABORT" in [c["name"] for c in robot.commands()[mark:]], 20, "the failsafe hold's ABORT")
        assert failsafe_after >= 10.0, failsafe_after  # the robot's failsafe_timeout_s, counted from the loss
        with site.lock:
            detail = next(e.detail for e in site.events[events:] if e.kind == "failsafe")
        assert "hold" in detail, detail
        wait_until(lambda: site.state.link == "failsafe", 10, "the failsafe in force in the GRI state")
    finally:
        if qgc is not None:
            qgc.close()
        gw.close()
