"""The fleet mesh over mutual TLS (docs/fleet.md, "A mesh over mutual TLS"), by attack.

A hub (ground) router with its own certificate and policy (``cromat certs --hub``), and the secured robot of
``uav1_secure.toml`` launched with the hub as its ``tls/`` peer (``[bus.tls] hubs``, ``mesh_robots``); every
certificate from ``cromat certs`` in tmp_path, one fleet CA. A ground station connected to the hub posts a fleet
task: the robot's RAL bids, decides, and its goto reaches the DSP simulator (its record); the station sees the
decision. A router identity of another robot (a real ``router-uav2`` certificate from ``cromat certs --robot
uav2``, linked to the robot's router as a Zenoh peer) posts a fleet task, submits a GRI goto, and puts a DSP
command batch on the robot's key: none of it reaches the RAL or the DSP simulator; its own robot's put does
arrive at a subscriber on the robot's router (the control that lets the test fail). It also publishes a fleet
state on its own robot's key (which its router may write) carrying forged fleet tasks: one unsigned, one signed by
the station with its target moved afterwards, one signed with the peer router's own key; beside them a task the
station did sign (relayed, as RALs do): the robot adopts and flies that one (the control) and refuses the
forgeries (bbcs/signing.py): never bid on, never relayed, nothing of them at the DSP simulator. A write of the
robot's own command key relayed by the hub is refused by the robot's router. Every station's fleet task is signed
with its TLS identity. Two launched robots linked only to a hub share a fleet task the station on the hub posted.
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts import dsp
from bbcs.contracts import tasks as t
from bbcs.contracts import world as w
from bbcs.contracts.fleet import FleetState, FleetTarget, FleetTask
from bbcs.contracts.robot import GeoPoint
from bbcs.session import SessionConfig, TlsConfig, open_session
from bbcs.signing import StationSigner
from bbcs.testing import child_env, free_port, wait_until
from cromat import certs
from ral.fleet_gcs import FleetView
from ral.gcs import fleet_cmd
from ral.gcs.api import Gcs, NoReply, session_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_secure_launch import MODULES, ROBOT, Robot, SecureLaunch, secure_manifest  # noqa: E402

PEER = "uav2"
HUB = "hub"


@dataclass
class Mesh:
    robot: Robot
    hub_port: int
    hub_log: Path
    peer_pki: Path

    def station(self) -> Gcs:
        """A ground station connected to the hub (not to the robot), presenting the ``gcs`` certificate."""
        ground = self.robot.pki.with_name("pki-ground")
        return Gcs(session_config([f"tls/127.0.0.1:{self.hub_port}"], ca=str(ground / "ca.pem"),
                                  cert=str(ground / "gcs.pem"), key=str(ground / "gcs.key"), connect_timeout_s=10.0),
                   name="gcs", link=[ROBOT], timeout_s=10.0)

    def signer(self) -> StationSigner:
        """The ground station's signing identity: its own TLS certificate and key (ground folder)."""
        ground = self.robot.pki.with_name("pki-ground")
        return StationSigner.from_files(ground / "gcs.pem", ground / "gcs.key")

    def peer_router(self) -> SessionConfig:
        """Another robot's router identity (CN router-uav2) linked to the robot's router as a Zenoh peer."""
        pki = self.peer_pki
        return SessionConfig(mode="peer", listen=[], connect=[f"tls/127.0.0.1:{self.robot.launch.port}"],
                             tls=TlsConfig(root_ca=str(pki / "ca.pem"), cert=str(pki / "router.pem"),
                                           key=str(pki / "router.key")), connect_timeout_s=10.0)


@pytest.fixture
def mesh(tmp_path: Path) -> Iterator[Mesh]:
    robot_port, hub_port = free_port(), free_port()
    manifest, pki = secure_manifest(tmp_path, robot_port)
    text = manifest.read_text()
    listen = f'listen = ["tls/127.0.0.1:{robot_port}"]'
    tls = 'ral = "ral"          # the module that is the RAL'
    assert text.count(listen) == 1 and text.count(tls) == 1
    manifest.write_text(text.replace(listen, f'{listen}\npeers = ["tls/127.0.0.1:{hub_port}"]')
                        .replace(tls, f'hubs = ["{HUB}"]\nmesh_robots = ["{PEER}"]\n{tls}'))
    ca = tmp_path / "pki-ca"
    assert certs.main(["--manifest", str(manifest)]) == 0
    assert certs.main([str(tmp_path / HUB), "--hub", HUB, "--ca", str(ca), "--robots", ROBOT,
                       "--acl", str(tmp_path / "hub.json5"), "--listen", f"tls/127.0.0.1:{hub_port}"]) == 0
    assert certs.main([str(tmp_path / PEER), "--robot", PEER, "--ca", str(ca), "--no-local", "--module", "probe",
                       "--ground", str(tmp_path / f"{PEER}-ground")]) == 0
    hub_log = tmp_path / "hub.log"
    with hub_log.open("w") as out:
        hub = subprocess.Popen([sys.executable, "-m", "bbcs.router", "--config", str(tmp_path / "hub.json5"),
                                "--listen", f"tls/127.0.0.1:{hub_port}", "--log-refusals"],
                               env=child_env(), stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    la: SecureLaunch | None = None
    try:
        wait_until(lambda: "listening on" in hub_log.read_text(), 30, "the hub router listening")
        la = SecureLaunch(manifest, tmp_path, robot_port)
        la.wait_line(f"all {len(MODULES)} modules up", 90)
        # the duplicate-name check reached the hub over mTLS as the router's identity (router-uav1)
        la.wait_line(f"robot name {ROBOT!r} is free on the mesh (tls/127.0.0.1:{hub_port})", 1)
        yield Mesh(Robot(la, pki, tmp_path), hub_port, hub_log, tmp_path / PEER)
    finally:
        _stop_all([la] if la is not None else [], hub)


def _stop_all(launches: list[SecureLaunch], hub: subprocess.Popen) -> None:
    """Every launch stopped and cleaned up, newest first, then the hub router, even if one of them fails."""
    try:
        for la in reversed(launches):
            try:
                la.stop()
            finally:
                la.cleanup()
    finally:
        hub.terminate()
        hub.wait(10)


def _home_through_hub(gcs: Gcs) -> GeoPoint:
    """The robot's home once the station on the hub sees its position: its state crossed robot router -> hub."""
    wait_until(lambda: (st := gcs.state(ROBOT)).position is not None and st.home is not None, 60,
               "the robot's position seen through the hub")
    home = gcs.state(ROBOT).home
    assert home is not None
    return home


def _added(robot: Robot, mark: int) -> list[tuple[float, float]]:
    return [(round(c["fields"]["lat"], 4), round(c["fields"]["lon"], 4))
            for c in robot.commands()[mark:] if c["name"] == "ADD_WAYPOINT"]


@pytest.mark.timeout(240)
def test_a_hub_carries_ground_tasks_and_a_peer_robots_router_writes_only_its_own_robot(mesh: Mesh) -> None:
    robot = mesh.robot
    with mesh.station() as gcs:
        home = _home_through_hub(gcs)
        mark = len(robot.commands())
        view = FleetView(gcs.session)
        # the attack: another robot's router identity, linked straight to the robot's router
        got: list[str] = []
        own_key = keys.slot_key(PEER, "probe", "marker")
        ground = robot.pki.with_name("pki-ground")
        listener = open_session(session_config([f"tls/127.0.0.1:{robot.launch.port}"], ca=str(ground / "ca.pem"),
                                               cert=str(ground / "gcs.pem"), key=str(ground / "gcs.key")))
        try:
            sub = listener.declare_subscriber(own_key, lambda s: got.append(s.payload.to_bytes().decode()))
            forged_at = (round(home.lat - 0.0004, 4), round(home.lon - 0.0004, 4))
            goto_at = (round(home.lat - 0.0006, 4), round(home.lon + 0.0005, 4))
            dsp_at = (round(home.lat + 0.0007, 4), round(home.lon - 0.0006, 4))
            unsigned_at = (round(home.lat - 0.0007, 4), round(home.lon - 0.0002, 4))
            moved_at = (round(home.lat - 0.0002, 4), round(home.lon + 0.0007, 4))
            self_signed_at = (round(home.lat + 0.0002, 4), round(home.lon - 0.0008, 4))
            with Gcs(mesh.peer_router(), name="router-uav2", timeout_s=3.0) as peer:
                FleetView(peer.session).post(FleetTask(id="forged", targets=[FleetTarget(
                    id="f0", lat=forged_at[0], lon=forged_at[1], alt=home.alt + 10.0)], posted_by="gcs"))
                with pytest.raises(NoReply):
                    peer.send(ROBOT, t.Goto(waypoints=[t.Waypoint(lat=goto_at[0], lon=goto_at[1],
                                                                  alt=home.alt + 10.0)]))
                batch = dsp.DspCommands(sender="path_follower", commands=[dsp.AddWaypoint(
                    lat=dsp_at[0], lon=dsp_at[1], alt=home.alt + 10.0)])
                peer.session.put(keys.slot_key(ROBOT, dsp.MODULE, dsp.commands_slot("path_follower")),
                                 msgspec.msgpack.encode(batch))
                # a taken robot relays fleet tasks in its own fleet state (its router may write that key): one a
                # ground station signed (relayed, as RALs do: the control, adopted) beside forgeries in the same
                # sample: unsigned, a signed task with a moved target, one signed with the peer router's own key
                relayed_at = (round(home.lat + 0.0005, 4), round(home.lon - 0.0003, 4))
                relayed = mesh.signer().sign(FleetTask(id="relayed", targets=[FleetTarget(
                    id="r0", lat=relayed_at[0], lon=relayed_at[1], alt=home.alt + 10.0)], posted_by="gcs"))
                moved = msgspec.structs.replace(relayed, id="moved")
                moved = mesh.signer().sign(moved)
                moved = msgspec.structs.replace(moved, targets=[msgspec.structs.replace(
                    moved.targets[0], lat=moved_at[0], lon=moved_at[1])])
                peer_key = StationSigner.from_files(mesh.peer_pki / "router.pem", mesh.peer_pki / "router.key")
                state = FleetState(robot=PEER, kind="uav", stamp=0.0, tasks=[
                    FleetTask(id="unsigned", targets=[FleetTarget(id="u0", lat=unsigned_at[0], lon=unsigned_at[1],
                                                                  alt=home.alt + 10.0)], posted_by="gcs"),
                    moved,
                    peer_key.sign(FleetTask(id="self_signed", targets=[FleetTarget(
                        id="s0", lat=self_signed_at[0], lon=self_signed_at[1], alt=home.alt + 10.0)])),
                    relayed])
                peer.session.put(keys.fleet_state_key(PEER), msgspec.msgpack.encode(state))
                peer.session.put(own_key, b"after the forged writes")
                wait_until(lambda: got, 30, "the peer router's own-robot put at a subscriber on the robot's router")
            sub.undeclare()
        finally:
            listener.close()
        assert got == ["after the forged writes"]
        # the control: the signed task relayed in the peer's fleet state is adopted, decided, flown
        dec = view.wait(lambda: view.agreed("relayed", {ROBOT}), 30)
        assert dec is not None and dec.routes[ROBOT] == ["r0"], view.decisions("relayed")
        wait_until(lambda: relayed_at in _added(robot, mark), 60, "the relayed signed task's target at the DSP")
        # the forgeries of the same sample were refused by the RAL, each with its reason, never bid on
        ral_log = robot.folder / "logs" / "ral.log"
        for why in ("unsigned from uav2's fleet state refused: not signed by a ground station",
                    "moved from uav2's fleet state refused: signature by 'gcs' does not match the task",
                    "self_signed from uav2's fleet state refused: signer 'router-uav2' is not a ground station"):
            wait_until(lambda why=why: why in ral_log.read_text(errors="replace"), 10, f"{why!r} in the RAL's log")
        for forged in ("unsigned", "moved", "self_signed"):
            assert view.answered(forged) == set() and view.decisions(forged) == {}, forged
        # a write of this robot's keys relayed by the hub (here from a session presenting this robot's own router
        # certificate, which the hub admits for uav1's keys) is refused by the robot's router: a hub never writes
        # this robot's keys
        relay_at = (round(home.lat + 0.0008, 4), round(home.lon + 0.0008, 4))
        command_key = keys.slot_key(ROBOT, dsp.MODULE, dsp.commands_slot("path_follower"))
        relayed = open_session(SessionConfig(mode="client", connect=[f"tls/127.0.0.1:{mesh.hub_port}"],
                                             tls=TlsConfig(root_ca=str(robot.pki / "ca.pem"),
                                                           cert=str(robot.pki / "router.pem"),
                                                           key=str(robot.pki / "router.key"))))
        try:
            relayed.put(command_key, msgspec.msgpack.encode(dsp.DspCommands(sender="path_follower", commands=[
                dsp.AddWaypoint(lat=relay_at[0], lon=relay_at[1], alt=home.alt + 10.0)])))
            wait_until(lambda: f"denied: hub may not put on {command_key}" in robot.router_log(), 30,
                       "the robot's router refusing the hub's relay of its own command key")
        finally:
            relayed.close()
        # the ground station's fleet task, through the hub: bid, decision, the target to the DSP simulator
        target = (round(home.lat + 0.0003, 4), round(home.lon + 0.0002, 4))
        try:
            view.post(FleetTask(id="mesh_t1", targets=[FleetTarget(id="m0", lat=target[0], lon=target[1],
                                                                   alt=home.alt + 10.0)], posted_by="gcs"),
                      mesh.signer())
            dec = view.wait(lambda: view.agreed("mesh_t1", {ROBOT}), 30)
            assert dec is not None and dec.bidders == [ROBOT] and dec.routes[ROBOT] == ["m0"], view.decisions(
                "mesh_t1")
            wait_until(lambda: target in _added(robot, mark), 60, "the fleet target at the DSP simulator")
            # the forged fleet task was posted before the real one: had it got through, the RAL would have answered
            assert view.answered("forged") == set() and view.decisions("forged") == {}
            for forged in ("unsigned", "moved", "self_signed"):
                assert view.answered(forged) == set() and view.decisions(forged) == {}, forged
            # and none of them is relayed in the robot's own fleet state
            assert {x.id for x in view.states[ROBOT].tasks} == {"relayed", "mesh_t1"}, view.states[ROBOT].tasks
        finally:
            view.close()
        added = _added(robot, mark)
        assert not {forged_at, goto_at, dsp_at, relay_at, unsigned_at, moved_at, self_signed_at} & set(added), added
        gcs.send(ROBOT, t.Hold())
    for denied in (f"router-uav2 may not put on {keys.fleet_task_key('forged')}",
                   f"router-uav2 may not query on {keys.ral_key(ROBOT, 'task')}",
                   f"router-uav2 may not put on {keys.slot_key(ROBOT, 'dsp', 'commands_path_follower')}"):
        # the router's log reader runs beside Zenoh's routing: its line may follow the refusal by a moment
        wait_until(lambda denied=denied: denied in robot.router_log(), 30, f"{denied!r} in the router's log")
    log = robot.router_log()
    # the hub's link and the robot's own identities were never refused: the mesh needs no right it lacks
    others = [line for line in log.splitlines() if " denied: " in line and "router-uav2" not in line
              and f"denied: hub may not put on {command_key}" not in line]
    assert others == [], others
    # the hub refuses only the robot's router relaying the peer identity's fleet state (uav2's key under
    # router-uav1's CN: a robot's router carries its own robot's keys only)
    relayed_state = f"router-{ROBOT} may not put on {keys.fleet_state_key(PEER)}"
    assert [line for line in mesh.hub_log.read_text().splitlines()
            if " denied: " in line and relayed_state not in line] == []


def _robot_manifest(folder: Path, name: str, port: int, peer: str, peer_port: int | None) -> tuple[Path, Path]:
    """uav1_secure.toml renamed ``name`` in ``folder`` on ``port``, with ``peer`` as its mesh robot (dialed when
    ``peer_port`` is given)."""
    folder.mkdir()
    manifest, pki = secure_manifest(folder, port)
    text = manifest.read_text()
    listen = f'listen = ["tls/127.0.0.1:{port}"]'
    tls = 'ral = "ral"          # the module that is the RAL'
    for old in ('name = "uav1"', listen, tls):
        assert text.count(old) == 1, old
    dial = f'\npeers = ["tls/127.0.0.1:{peer_port}"]' if peer_port is not None else ""
    manifest.write_text(text.replace('name = "uav1"', f'name = "{name}"').replace(listen, listen + dial)
                        .replace(tls, f'mesh_robots = ["{peer}"]\n{tls}'))
    return manifest, pki


@pytest.mark.timeout(300)
def test_two_secured_robots_linked_directly_share_their_state_and_refuse_each_others_commands(
        tmp_path: Path) -> None:
    """No hub: uav1's router dials uav2's over mTLS (``mesh_robots`` on both). A ground station on uav1's router
    sees uav2 (its RAL's token, GRI state and fleet state, with their history, crossed uav2's router → uav1's under
    CN router-uav2). The station's fleet-task put reaches uav2's router under router-uav1's CN and is refused
    there, yet uav2 learns the task from uav1's fleet state (uav1's own key) and both agree: RALs relay the tasks
    they know. A command query from that station to uav2 is refused (by uav1's router already; router-uav1 has no
    ground-station rights on uav2's either).
    Neither router refuses anything else of the robots' own traffic."""
    ca = tmp_path / "pki-ca"
    p1, p2 = free_port(), free_port()
    m2, pki2 = _robot_manifest(tmp_path / PEER, PEER, p2, ROBOT, None)
    m1, pki1 = _robot_manifest(tmp_path / ROBOT, ROBOT, p1, PEER, p2)
    for manifest in (m1, m2):
        assert certs.main(["--manifest", str(manifest), "--ca", str(ca)]) == 0
    launches: list[SecureLaunch] = []
    try:
        for manifest, folder, port in ((m2, tmp_path / PEER, p2), (m1, tmp_path / ROBOT, p1)):
            launches.append(SecureLaunch(manifest, folder, port))
        for la in launches:
            la.wait_line(f"all {len(MODULES)} modules up", 120)
        r1, r2 = Robot(launches[1], pki1, tmp_path / ROBOT), Robot(launches[0], pki2, tmp_path / PEER)
        with r1.client("gcs", name="gcs", link=[ROBOT], timeout_s=10.0) as gcs:
            wait_until(lambda: gcs.robots(2.0) == [ROBOT, PEER], 60, "both robots seen on uav1's router")
            wait_until(lambda: gcs.state(PEER).position is not None, 60, "uav2's GRI state on uav1's router")
            wait_until(lambda: gcs.state(ROBOT).home is not None, 60, "uav1's take-off point")
            home = gcs.state(ROBOT).home
            assert home is not None
            view = FleetView(gcs.session)
            try:
                assert view.wait(lambda: PEER in view.states and ROBOT in view.states, 30), sorted(view.states)
                target = (round(home.lat + 0.0003, 4), round(home.lon + 0.0002, 4))
                marks = {ROBOT: len(r1.commands()), PEER: len(r2.commands())}
                ground = pki1.with_name("pki-ground")
                signed = view.post(FleetTask(id="direct_t1", targets=[FleetTarget(
                    id="d0", lat=target[0], lon=target[1], alt=home.alt + 10.0)], posted_by="gcs"),
                    StationSigner.from_files(ground / "gcs.pem", ground / "gcs.key"))
                # the put itself is refused by uav2's router (it arrives under router-uav1's CN) ... once uav1's
                # router relays it: it does so only after it has learnt uav2's subscription to fleet tasks, which
                # the post's wait cannot see (it is satisfied by uav1's own RAL). So the same signed bytes are put
                # again until uav2's router has refused one (a clean-clone run at load waited 30 s for one put)
                fleet = f"router-{ROBOT} may not put on {keys.fleet_task_key('direct_t1')}"
                again = time.monotonic() + 3.0
                end = time.monotonic() + 30.0
                while fleet not in r2.router_log():
                    assert time.monotonic() < end, "uav2's router refusing the relayed fleet task"
                    if time.monotonic() >= again:
                        gcs.session.put(keys.fleet_task_key("direct_t1"), msgspec.msgpack.encode(signed))
                        again = time.monotonic() + 3.0
                    time.sleep(0.1)
                # ... and uav2 learns the task from uav1's fleet state, uav1's own key (RALs relay the tasks they
                # know, for late joiners and partitions: docs/fleet.md); both bid and agree
                dec = view.wait(lambda: view.agreed("direct_t1", {ROBOT, PEER}), 30)
                assert dec is not None and dec.bidders == [ROBOT, PEER], view.decisions("direct_t1")
                flier = next(r for r, route in dec.routes.items() if route == ["d0"])
                at = {ROBOT: r1, PEER: r2}[flier]
                wait_until(lambda: target in _added(at, marks[flier]), 60, f"the fleet target at {flier}'s DSP")
            finally:
                view.close()
            gcs.send(ROBOT, t.Hold())
            with pytest.raises(NoReply):  # uav2 is not this station's to command: its own router refuses that
                gcs.send(PEER, t.Hold(), timeout_s=3.0)
        task_query = f"gcs may not query on {keys.ral_key(PEER, 'task')}"
        wait_until(lambda: task_query in r1.router_log(), 30, "uav1's router refusing the command to uav2")
        # the station's link (token, heartbeats on cromat/@gcs/**) is uav1's only: uav2's router refuses it too
        link = re.compile(rf"denied: router-{ROBOT} may not (liveliness token|undeclare liveliness token|put) on "
                          rf"\S*{re.escape(keys.gcs_key('gcs'))}[/ `]")
        wait_until(lambda: link.search(r2.router_log()), 30, "uav2's router refusing uav1's station's link")
        for robot, allowed in ((r1, [task_query]), (r2, [fleet])):
            denied = [line for line in robot.router_log().splitlines() if " denied: " in line
                      and not any(a in line for a in allowed) and not (robot is r2 and link.search(line))]
            assert denied == [], denied
    finally:
        for la in reversed(launches):
            try:
                la.stop()
            finally:
                la.cleanup()


def _square(lat: float, lon: float, half: float = 0.0002) -> list[t.Vertex]:
    return [t.Vertex(lat=lat - half, lon=lon - half), t.Vertex(lat=lat - half, lon=lon + half),
            t.Vertex(lat=lat + half, lon=lon + half), t.Vertex(lat=lat + half, lon=lon - half)]


@pytest.mark.timeout(240)
def test_a_peer_robots_router_cannot_remove_a_station_signed_zone_nor_add_its_own(mesh: Mesh) -> None:
    """Zone edits signed by the ground station (docs/world.md), by attack over real Zenoh: the station on the hub
    adds a no-fly zone through the robot (unsigned: refused; signed: applied). The peer robot's router identity
    publishes on its own ``@ral/world`` key (which its router may write) an update removing that zone (unsigned,
    and with the signature of a removal the station signed for another id), adding an unsigned zone, and its own
    robot's target (the control: robots' own entries are not signed, so it arrives); then serves them, and one
    more fake zone, as its snapshot (``@ral/world_model``, asked for on a differing digest). The robot keeps the zone (a
    goto into it is refused, nothing of it at the DSP simulator) and never holds the fake one; the station's signed
    removal still applies (the same goto then reaches the DSP simulator)."""
    robot = mesh.robot
    with mesh.station() as gcs:
        home = _home_through_hub(gcs)
        zone_at = (round(home.lat + 0.0005, 4), round(home.lon + 0.0005, 4))
        fake_at = (round(home.lat - 0.0005, 4), round(home.lon - 0.0005, 4))
        marker_at = (round(home.lat - 0.0003, 4), round(home.lon + 0.0003, 4))
        zone = w.NoFlyZone(polygon=_square(*zone_at), name="radio mast")
        unsigned = fleet_cmd.world_request(gcs, ROBOT, w.WorldPut(id="mast", body=zone, author="gcs"))
        assert not unsigned.accepted and "not signed by a ground station" in unsigned.reason, unsigned.reason
        added = fleet_cmd.world_request(gcs, ROBOT, w.WorldPut(id="mast", body=zone, author="gcs"), mesh.signer())
        assert added.accepted and added.entry is not None and added.entry.signature, added.reason
        other = fleet_cmd.signed_request(w.WorldDelete(id="old_tower"), mesh.signer())
        seen = w.Target(lat=home.lat, lon=home.lon, alt=home.alt, seen_by=PEER, seen_at=1.0)
        update = w.WorldUpdate(robot=PEER, entries=[
            w.WorldEntry(id="mast", version=5, origin=PEER, stamp=1.0, deleted=True, author="gcs"),
            w.WorldEntry(id="mast", version=6, origin=PEER, stamp=1.0, deleted=True, author="gcs",
                         signer_cert=other.signer_cert, signature=other.signature),
            w.WorldEntry(id="fake", version=1, origin=PEER, stamp=1.0, author="gcs",
                         body=w.NoFlyZone(polygon=_square(*fake_at, 0.001))),
            w.WorldEntry(id=f"target.{PEER}", version=1, origin=PEER, stamp=1.0, body=seen)])

        def held() -> dict[str, w.WorldEntry]:
            return {e.id: e for e in fleet_cmd.world_snapshot(gcs, ROBOT).entries}

        with Gcs(mesh.peer_router(), name="router-uav2", timeout_s=3.0) as peer:
            def published() -> bool:  # again until the robot's subscription has reached the new peer link
                peer.session.put(w.world_key(PEER), msgspec.msgpack.encode(update))
                return f"target.{PEER}" in held()

            wait_until(published, 30, "the peer's own target in the robot's world model (the control)")
            # the same forgeries and one more in the peer's snapshot, which the robot asks for when the peer's
            # digest differs from its own (anti-entropy); the peer's target, a version on, is the control
            fake2 = w.WorldEntry(id="fake2", version=1, origin=PEER, stamp=1.0,
                                 body=w.Geofence(polygon=_square(*fake_at, 0.001)))
            control = msgspec.structs.replace(update.entries[-1], version=2)
            snapshot = w.WorldSnapshot(robot=PEER, digest="forged", entries=[*update.entries[:-1], fake2, control])
            served = peer.session.declare_queryable(w.world_model_key(PEER), lambda q: q.reply(
                w.world_model_key(PEER), msgspec.msgpack.encode(snapshot)))
            try:
                def asked() -> bool:
                    peer.session.put(w.world_digest_key(PEER), msgspec.msgpack.encode(
                        w.WorldDigest(robot=PEER, digest="forged", entries=len(snapshot.entries))))
                    return held()[f"target.{PEER}"].version == 2

                wait_until(asked, 30, "the peer's snapshot merged by the robot (its target, version 2)")
            finally:
                served.undeclare()
        model = held()
        assert model["mast"] == added.entry and "fake" not in model and "fake2" not in model, model
        ral_log = robot.folder / "logs" / "ral.log"
        source = f"from the update on {w.world_key(PEER)} refused"
        for why in (f"removal of 'mast' v5 {source}: not signed by a ground station",
                    f"removal of 'mast' v6 {source}: signature by 'gcs' does not match the edit",
                    f"entry 'fake' v1 {source}: not signed by a ground station",
                    f"entry 'fake2' v1 from {PEER}'s snapshot refused: not signed by a ground station"):
            wait_until(lambda why=why: why in ral_log.read_text(errors="replace"), 10, f"{why!r} in the RAL's log")
            assert ral_log.read_text(errors="replace").count(why) == 1, why  # logged once, however often it came
        # by effect: a goto into the zone is refused and sends nothing; a marker goto after it reaches the DSP (a path
        # is flown from the air: the take-off first)
        took = gcs.send(ROBOT, t.TakeOff())
        assert took.accepted, took.reason
        wait_until(lambda: bool((st := gcs.state(ROBOT)).airborne) and not any(x.kind == "take_off" for x in st.tasks),
                   120, "airborne, the take-off done")
        mark = len(robot.commands())
        into = t.Goto(waypoints=[t.Waypoint(lat=zone_at[0], lon=zone_at[1], alt=home.alt + 10.0)])
        reply = gcs.send(ROBOT, into)
        assert not reply.accepted and "no-fly zone 'mast' (radio mast)" in reply.reason, reply.reason
        reply = gcs.send(ROBOT, t.Goto(waypoints=[t.Waypoint(lat=marker_at[0], lon=marker_at[1],
                                                             alt=home.alt + 10.0)]))
        assert reply.accepted, reply.reason
        wait_until(lambda: marker_at in _added(robot, mark), 60, "the marker goto at the DSP simulator")
        assert zone_at not in _added(robot, mark)
        # the station's signed removal still applies, and the same goto then flies
        removed = fleet_cmd.world_request(gcs, ROBOT, w.WorldDelete(id="mast", author="gcs"), mesh.signer())
        assert removed.accepted and removed.entry is not None and removed.entry.deleted, removed.reason
        reply = gcs.send(ROBOT, into)
        assert reply.accepted, reply.reason
        wait_until(lambda: zone_at in _added(robot, mark), 60, "the goto into the removed zone at the DSP")
        assert fake_at not in _added(robot, mark) and "fake" not in held()
        gcs.send(ROBOT, t.Hold())


def _hub_robot_manifest(folder: Path, name: str, port: int, hub_port: int,
                        home: tuple[float, float, float]) -> tuple[Path, Path]:
    """uav1_secure.toml renamed ``name`` in ``folder`` on ``port``, its router dialing the hub (``hubs`` and
    ``peers``: no ``mesh_robots``, no direct link to another robot), its DSP simulator taking off from ``home``."""
    folder.mkdir()
    manifest, pki = secure_manifest(folder, port)
    text = manifest.read_text()
    listen = f'listen = ["tls/127.0.0.1:{port}"]'
    tls = 'ral = "ral"          # the module that is the RAL'
    record = f'"--record", "{folder / "dsp.jsonl"}"]'
    for old in ('name = "uav1"', listen, tls, record):
        assert text.count(old) == 1, old
    manifest.write_text(text.replace('name = "uav1"', f'name = "{name}"')
                        .replace(listen, f'{listen}\npeers = ["tls/127.0.0.1:{hub_port}"]')
                        .replace(tls, f'hubs = ["{HUB}"]\n{tls}')
                        .replace(record, f'{record[:-1]}, "--home", "{",".join(map(str, home))}"]'))
    return manifest, pki


@pytest.mark.timeout(300)
def test_a_hub_carries_a_signed_fleet_task_and_the_fleet_state_between_two_launched_robots(tmp_path: Path) -> None:
    """Two secured robots, each with its own router and DSP simulator (homes ~220 m apart), linked over mTLS only
    to a hub router (``hubs`` and ``peers``; no link between them). A ground station on the hub posts one signed
    fleet task, one target near each robot, at most one per robot: each robot's bids cross its router → the hub
    → the other's router (under the hub's CN, which may relay every robot's writes), both RALs decide the same
    allocation with both bidders, each flies the target nearer to it (at its own DSP simulator, the other's target
    never), the station sees both decisions, and no router refuses any of this legitimate traffic."""
    ca = tmp_path / "pki-ca"
    hub_port, p1, p2 = free_port(), free_port(), free_port()
    homes = {ROBOT: (37.4117, -6.0025, 12.0), PEER: (37.4137, -6.0025, 12.0)}
    m1, pki1 = _hub_robot_manifest(tmp_path / ROBOT, ROBOT, p1, hub_port, homes[ROBOT])
    m2, pki2 = _hub_robot_manifest(tmp_path / PEER, PEER, p2, hub_port, homes[PEER])
    for manifest in (m1, m2):
        assert certs.main(["--manifest", str(manifest), "--ca", str(ca)]) == 0
    assert certs.main([str(tmp_path / HUB), "--hub", HUB, "--ca", str(ca), "--robots", f"{ROBOT},{PEER}",
                       "--acl", str(tmp_path / "hub.json5"), "--listen", f"tls/127.0.0.1:{hub_port}"]) == 0
    hub_log = tmp_path / "hub.log"
    with hub_log.open("w") as out:
        hub = subprocess.Popen([sys.executable, "-m", "bbcs.router", "--config", str(tmp_path / "hub.json5"),
                                "--listen", f"tls/127.0.0.1:{hub_port}", "--log-refusals"],
                               env=child_env(), stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    launches: list[SecureLaunch] = []
    try:
        wait_until(lambda: "listening on" in hub_log.read_text(), 30, "the hub router listening")
        for manifest, name, port in ((m1, ROBOT, p1), (m2, PEER, p2)):
            launches.append(SecureLaunch(manifest, tmp_path / name, port))
        for la, name in zip(launches, (ROBOT, PEER), strict=True):
            la.wait_line(f"all {len(MODULES)} modules up", 120)
            la.wait_line(f"robot name {name!r} is free on the mesh (tls/127.0.0.1:{hub_port})", 1)
        robots = {ROBOT: Robot(launches[0], pki1, tmp_path / ROBOT), PEER: Robot(launches[1], pki2, tmp_path / PEER)}
        ground = pki1.with_name("pki-ground")
        station = Gcs(session_config([f"tls/127.0.0.1:{hub_port}"], ca=str(ground / "ca.pem"),
                                     cert=str(ground / "gcs.pem"), key=str(ground / "gcs.key"),
                                     connect_timeout_s=10.0), name="gcs", link=[ROBOT, PEER], timeout_s=10.0)
        with station as gcs:
            wait_until(lambda: gcs.robots(2.0) == [ROBOT, PEER], 60, "both robots seen on the hub")
            for name in (ROBOT, PEER):
                wait_until(lambda name=name: (st := gcs.state(name)).position is not None and st.home is not None,
                           60, f"{name}'s position through the hub")
            home = {name: gcs.state(name).home for name in (ROBOT, PEER)}
            assert all(abs(h.lat - homes[n][0]) < 1e-4 for n, h in home.items() if h is not None), home
            near = {name: (round(h.lat + 0.0003, 4), round(h.lon + 0.0002, 4)) for name, h in home.items()
                    if h is not None}
            view = FleetView(gcs.session)
            try:
                assert view.wait(lambda: {ROBOT, PEER} <= set(view.states), 30), sorted(view.states)
                marks = {name: len(r.commands()) for name, r in robots.items()}
                view.post(FleetTask(id="hub_t1", one_per_robot=True, posted_by="gcs", targets=[
                    FleetTarget(id=f"near_{name}", lat=lat, lon=lon, alt=homes[name][2] + 10.0)
                    for name, (lat, lon) in near.items()]),
                          StationSigner.from_files(ground / "gcs.pem", ground / "gcs.key"))
                # both decisions, the same on both robots, with both bidders: each RAL had the other's bids, which
                # travel in its fleet state (cromat/<robot>/@ral/fleet) from its router through the hub to the other's
                dec = view.wait(lambda: view.agreed("hub_t1", {ROBOT, PEER}), 30)
                assert dec is not None, view.decisions("hub_t1")
                assert set(view.decisions("hub_t1")) == {ROBOT, PEER}
                assert dec.bidders == [ROBOT, PEER] and dec.unassigned == [], dec
                assert dec.routes == {ROBOT: [f"near_{ROBOT}"], PEER: [f"near_{PEER}"]}, dec.routes
                for name, robot in robots.items():
                    wait_until(lambda name=name, robot=robot: near[name] in _added(robot, marks[name]), 60,
                               f"{name}'s near target at its DSP simulator")
            finally:
                view.close()
            for name, robot in robots.items():
                other = PEER if name == ROBOT else ROBOT
                assert near[other] not in _added(robot, marks[name]), (name, _added(robot, marks[name]))
                assert gcs.send(name, t.Hold()).accepted, name  # a command through the hub, too
        # neither robot's router (nor the hub) refused anything: the hub relays the station's task and link and
        # each robot's fleet state to the other without a right missing
        for name, robot in robots.items():
            assert "cromat router: listening on" in robot.router_log(), name  # its log is there to read
            assert [line for line in robot.router_log().splitlines() if " denied: " in line] == [], name
        assert [line for line in hub_log.read_text().splitlines() if " denied: " in line] == []
    finally:
        _stop_all(launches, hub)
