"""Issue 6, security on a launched robot: ``cromat launch bbcs_conf/uav1_secure.toml`` (router with mTLS and
the access policy, DSP simulator, DSP, telemetry, pan & tilt, path follower, vision, RAL) as a process tree,
every certificate made by ``cromat certs --manifest`` in tmp_path.

A GCS presenting the ``gcs`` certificate sees the robot and gets a pan & tilt task accepted and carried out
(RAL → pan & tilt → DSP through the policy); a client presenting a module's certificate is denied tasks and
route swaps and the robot is unaffected; a client without a certificate is refused; every identity reads
the state.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts import gri, mri
from bbcs.contracts import tasks as t
from bbcs.contracts.fleet import FleetTarget, FleetTask
from bbcs.contracts.path_follower import DatosSegCam
from bbcs.contracts.trajectory import OrbitRequest, TrajectoryRequest, TrajectoryStatus, Vertex
from bbcs.signing import StationSigner
from bbcs.testing import child_env, free_port, put_until_heard, wait_until
from cromat import certs
from module_manager.manifest import ManifestError, load_manifest
from ral.fleet_gcs import FleetView
from ral.gcs.api import Gcs, NoReply, Unreachable, session_config

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "module_manager"))
from launch_support import ROOT, Launch  # noqa: E402

from modules.dsp.sim.record import read_record

ROBOT = "uav1"
MANIFEST = ROOT / "bbcs_conf" / "uav1_secure.toml"
MODULES = {"dsp", "telemetry", "pan_tilt", "path_follower", "vision", "trajectory", "ral"}
TIME_SCALE = 4.0


def secure_manifest(tmp_path: Path, port: int) -> tuple[Path, Path]:
    """uav1_secure.toml with an absolute .conf, the pki folder in ``tmp_path`` and the router on ``port``."""
    pki = tmp_path / "pki"
    text = MANIFEST.read_text()
    for old, new in (
        ('conf = "uav1.conf"', f'conf = "{MANIFEST.parent / "uav1.conf"}"'),
        ('pki = "pki"', f'pki = "{pki}"'),
        ('listen = ["tls/127.0.0.1:7447"]', f'listen = ["tls/127.0.0.1:{port}"]'),
        ('"--tcp", "127.0.0.1:{port:dsp}"]',
         f'"--tcp", "127.0.0.1:{{port:dsp}}", "--time-scale", "{TIME_SCALE:g}", '
         f'"--record", "{tmp_path / "dsp.jsonl"}"]'),
    ):
        assert text.count(old) == 1, f"{old!r} changed in uav1_secure.toml"
        text = text.replace(old, new)
    path = tmp_path / "uav1_secure.toml"
    path.write_text(text)
    return path, pki


class SecureLaunch(Launch):
    """``cromat launch`` of a manifest whose router listens on its own ``tls/`` endpoint (no ``--listen``)."""

    def __init__(self, manifest: Path, tmp_path: Path, port: int) -> None:
        self.port = port
        self.lines: list[str] = []
        self.cond = threading.Condition()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "module_manager.cli", str(manifest), "--log-dir", str(tmp_path / "logs")],
            cwd=str(ROOT), env=child_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            start_new_session=True)
        self.pgid = self.proc.pid
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()


@dataclass
class Robot:
    launch: SecureLaunch
    pki: Path
    folder: Path

    def commands(self) -> list[dict]:
        """Every command frame the DSP simulator received so far (its record; a half-written line waits)."""
        return read_record(self.folder / "dsp.jsonl")

    def router_log(self) -> str:
        path = self.folder / "logs" / "router.log"
        return path.read_text(errors="replace") if path.exists() else ""

    def client(self, identity: str | None, connect_timeout_s: float = 10.0, **kw: object) -> Gcs:
        """A TLS ground station; the generous connect deadline is for a loaded machine (a refused one: short)."""
        folder = self.pki.with_name("pki-ground") if identity == "gcs" else self.pki  # GCS pairs: never on the robot
        cert = str(folder / f"{identity}.pem") if identity else None
        key = str(folder / f"{identity}.key") if identity else None
        cfg = session_config([f"tls/127.0.0.1:{self.launch.port}"], ca=str(self.pki / "ca.pem"), cert=cert,
                             key=key, connect_timeout_s=connect_timeout_s)
        return Gcs(cfg, **kw)  # type: ignore[arg-type]


@contextmanager
def launched(manifest: Path, pki: Path, folder: Path, port: int) -> Iterator[Robot]:
    """``cromat launch`` of ``manifest`` (certificates already made) until every module is up; stopped and cleaned
    up on every path."""
    la = SecureLaunch(manifest, folder, port)
    try:
        la.wait_line(f"all {len(MODULES)} modules up", 90)
        yield Robot(la, pki, folder)
    finally:
        try:
            la.stop()
        finally:
            la.cleanup()


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Robot]:
    tmp = tmp_path_factory.mktemp("secure")
    port = free_port()
    manifest, pki = secure_manifest(tmp, port)
    assert certs.main(["--manifest", str(manifest)]) == 0
    with launched(manifest, pki, tmp, port) as robot:
        yield robot


def heard(session: object, marker: str, marks: list[bytes], what: bytes) -> None:
    """``what`` put on ``marker`` from ``session`` until the station's subscriber has it (``put_until_heard``)."""
    put_until_heard(lambda: session.put(marker, what), lambda: what in marks,  # type: ignore[attr-defined]
                    f"the attacker's marker {what!r}")


def sees_every_module(gcs: Gcs) -> None:
    """Wait until the station lists the robot and its state shows every module up (the manager saw each token)."""
    wait_until(lambda: gcs.robots(1.0) == [ROBOT], 30, "the robot in the GCS's robot list")
    wait_until(lambda: {m.name: m.state for m in gcs.state(ROBOT).modules} == {n: "up" for n in MODULES}, 30,
               "every module up in the robot state")


def test_certificates_are_exactly_what_the_manifest_needs(robot: Robot) -> None:
    made = {p.stem for p in robot.pki.glob("*.pem")}
    assert made == {"ca", "router", "manager", *MODULES}
    assert {p.stem for p in robot.pki.glob("*.key")} == made - {"ca"}  # no CA key, no GCS key on the robot
    assert {p.name for p in robot.pki.with_name("pki-ground").iterdir()} == {"ca.pem", "gcs.pem", "gcs.key"}
    assert (robot.pki.with_name("pki-ca") / "ca.key").is_file()


def test_gcs_identity_sees_the_robot_and_gets_a_task_done(robot: Robot) -> None:
    # no GCS link held (``link=``): its end would start the link-loss failsafe 10 s later, a hold whose ABORT would
    # land in the middle of the tests that follow on this robot (the history-injection test counts ABORTs)
    with robot.client("gcs", name="gcs", timeout_s=10.0) as gcs:
        sees_every_module(gcs)
        reply = gcs.send(ROBOT, gri.SetPanTilt(pan=30.0, tilt=-20.0))
        assert reply.accepted and reply.task_type == "pan_tilt", reply.reason
        # the angles travel GCS → RAL slot → pan & tilt → DSP mailbox → simulator → telemetry → state
        wait_until(lambda: (p := gcs.state(ROBOT).pan_deg) is not None and abs(p - 30.0) < 2.0, 90,
                   "pan at 30 degrees")
        assert any(t.kind == "pan_tilt" for t in gcs.state(ROBOT).tasks)


def test_the_legitimate_robot_is_never_denied(robot: Robot) -> None:
    """After the launch and a GCS task, before any attack: the router's log (--log-refusals, on by default on a
    secure launch) holds no denial, so the policy lets every module, the manager, the RAL and the GCS do their
    work (a module's advanced subscriber on its own CONTROL_ENTRADA included)."""
    assert "cromat router: listening on" in robot.router_log()
    assert [line for line in robot.router_log().splitlines() if " denied: " in line] == []


def test_module_identity_is_denied_tasks_and_route_swaps_and_robot_unaffected(robot: Robot) -> None:
    with robot.client("gcs", name="gcs", timeout_s=10.0) as gcs:
        before = gcs.state(ROBOT)
        routes = gcs.routes(ROBOT).routes
        with robot.client("pan_tilt", name="pan_tilt", timeout_s=2.0) as module:
            with pytest.raises(NoReply, match="may not submit"):
                module.send(ROBOT, gri.Land())
            with pytest.raises(NoReply):
                module.route(ROBOT, "pan_tilt", "datos", 20)
        # a request through the RAL's one worker queue after the denied ones, changing nothing; then a state the
        # RAL published after it was answered: anything that had got through would show in that state
        assert not gcs.send(ROBOT, gri.Cancel(task_type="no_such_type")).accepted
        seen = gcs.state(ROBOT)
        wait_until(lambda: gcs.state(ROBOT).stamp > seen.stamp, 30, "a state published after the marker")
        after = gcs.state(ROBOT)
        assert [(t.id, t.kind) for t in after.tasks] == [(t.id, t.kind) for t in before.tasks]
        assert not any(t.kind == "land" for t in after.tasks)
        assert gcs.routes(ROBOT).routes == routes
        assert {m.name: m.state for m in gcs.modules(ROBOT).modules} == {name: "up" for name in MODULES}


def test_only_a_ground_station_changes_a_run_time_parameter(robot: Robot) -> None:
    """``cromat param`` on a secured robot (issue 34): the gcs identity lists, reads and sets the trajectory
    generator's ``arc_step_deg`` (the manager hands the change to the module over ``trajectory/@params``, which
    the policy grants the manager alone: an accepted set is the module's answer); the vision identity, asking the
    manager or the module directly, gets no answer and the value stays."""
    from bbcs.contracts.params import GetParam, ListParams, SetParam, module_params_key

    def value(session: object) -> object:
        reply = mri.call(session, ROBOT, "param", GetParam(module="trajectory", name="arc_step_deg"), 10.0)
        assert reply.ok, reply.reason
        return reply.data.params[0].value  # type: ignore[union-attr]

    with robot.client("gcs", name="gcs", timeout_s=10.0) as gcs:
        listed = mri.call(gcs.session, ROBOT, "param", ListParams(module="trajectory"), 10.0)
        assert listed.ok and "arc_step_deg" in {p.name for p in listed.data.params}, listed  # type: ignore[union-attr]
        before = value(gcs.session)
        events: list[gri.GriEvent] = []
        gcs.events(ROBOT, events.append)
        changed = 9.0 if before != 9.0 else 8.0
        try:
            with robot.client("vision", name="intruder", timeout_s=3.0) as attacker:
                with pytest.raises(mri.MriError, match="no MRI reply"):
                    mri.call(attacker.session, ROBOT, "param",
                             SetParam(module="trajectory", name="arc_step_deg", value="45"), 3.0)
                direct = list(attacker.session.get(
                    module_params_key(ROBOT, "trajectory"),
                    payload=msgspec.msgpack.encode(SetParam(module="trajectory", name="arc_step_deg", value="45")),
                    timeout=3.0))
                assert not [r for r in direct if r.ok is not None], "the module answered another module's identity"
            assert value(gcs.session) == before
            reply = mri.call(gcs.session, ROBOT, "param",
                             SetParam(module="trajectory", name="arc_step_deg", value=f"{changed:g}"), 10.0)
            assert reply.ok, reply.reason
            assert value(gcs.session) == changed
            wait_until(lambda: any(e.kind == "param_changed" and "arc_step_deg" in e.detail for e in events), 15,
                       "the change as a GRI event")
        finally:
            mri.call(gcs.session, ROBOT, "param",
                     SetParam(module="trajectory", name="arc_step_deg", value=f"{before}"), 10.0)


def test_client_without_certificate_is_refused(robot: Robot) -> None:
    with pytest.raises(Unreachable, match="refused|reach"):
        robot.client(None, connect_timeout_s=3.0, timeout_s=2.0)


@pytest.mark.parametrize("identity", ["gcs", "pan_tilt", "dsp", "ral", "manager"])
def test_every_identity_reads_the_state(robot: Robot, identity: str) -> None:
    with robot.client(identity, name="reader", timeout_s=10.0) as station:
        assert station.robots() == [ROBOT]
        state = station.state(ROBOT)
        assert state.robot == ROBOT and state.manager_up
        assert {m.name for m in station.modules(ROBOT).modules} == MODULES


def test_missing_module_certificate_is_a_manifest_error_naming_the_file(robot: Robot, tmp_path: Path) -> None:
    pki = tmp_path / "pki"
    shutil.copytree(robot.pki, pki)
    (pki / "vision.key").unlink()
    manifest, _ = secure_manifest(tmp_path, free_port())
    with pytest.raises(ManifestError, match=r"modules\.vision: certificate file .*/pki/vision\.key does not exist"):
        load_manifest(manifest)
    # cromat launch refuses it before starting anything
    proc = subprocess.run([sys.executable, "-m", "module_manager.cli", str(manifest)], cwd=str(ROOT), env=child_env(),
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "vision.key" in proc.stderr and "router" not in proc.stdout


# --- issue 12's remaining gaps on the launched secure robot ------------------------------------------------

def test_a_denied_put_shows_in_the_router_log_naming_identity_and_key(robot: Robot) -> None:
    """A secure launch runs its router with --log-refusals: an attacker's denied put is in logs/router.log."""
    key = f"cromat/{ROBOT}/manager/pan_tilt_mode"
    with robot.client("vision", name="intruder", timeout_s=5.0) as attacker:
        attacker.session.put(key, b"forged")
        wait_until(lambda: f"denied: vision may not put on {key}" in robot.router_log(), 30,
                   "the denied put in the router's log")
    with robot.client("gcs", name="gcs", timeout_s=10.0) as gcs:  # and nothing of it reached the robot
        assert gcs.state(ROBOT).manager_up


@pytest.mark.parametrize("service", ["@ral", "@manager"])
def test_gcs_identity_reads_the_service_schemas(robot: Robot, service: str) -> None:
    """``cromat/uav1/@ral/@schema`` and ``@manager/@schema``, answered by the real RAL and manager."""
    key = f"cromat/{ROBOT}/{service}/@schema"
    with robot.client("gcs", name="gcs", timeout_s=10.0) as gcs:
        docs: list[dict] = []

        def fetch() -> bool:
            docs[:] = [json.loads(r.ok.payload.to_bytes()) for r in gcs.session.get(key, timeout=5.0)
                       if r.ok is not None]
            return bool(docs)
        wait_until(fetch, 30, f"an answer on {key}")
    assert len(docs) == 1
    expected = gri.state_key(ROBOT) if service == "@ral" else mri.mri_key(ROBOT, mri.STATE)
    assert expected in docs[0], sorted(docs[0])


def test_history_injection_on_the_live_robot_changes_nothing(robot: Robot) -> None:
    """Finding 1 on the launched robot: the vision identity declares advanced publishers (cache, publisher
    detection) on the path follower's mode slot with an Abort command and on the pan & tilt's CONTROL_ENTRADA
    with DATOS from slot 20. The modules' advanced subscribers ask late publishers for history, so before the
    policy the path follower sent ABORT to the DSP and pan & tilt read slot 20. Now: no ABORT reaches the DSP
    simulator, no RouteAck shows slot 20, the manager sees no drift; then a GCS hold does send ABORT."""
    import zenoh
    import zenoh.ext

    from bbcs.contracts.pan_tilt import ControlEntradaPT
    from bbcs.contracts.path_follower import ControlModoSegCam
    from bbcs.routing import RouteAck

    acks: list[RouteAck] = []
    marks: list[bytes] = []
    marker = f"cromat/{ROBOT}/vision/marker"
    with robot.client("gcs", name="gcs", timeout_s=10.0) as gcs:
        subs = [gcs.session.declare_subscriber(keys.route_ack_key(ROBOT, "pan_tilt"), lambda x: acks.append(
                    msgspec.msgpack.decode(x.payload.to_bytes(), type=RouteAck))),
                gcs.session.declare_subscriber(marker, lambda x: marks.append(x.payload.to_bytes()))]
        mark = len(robot.commands())
        try:
            with robot.client("vision", name="intruder", timeout_s=5.0) as attacker:
                forged = {
                    keys.slot_key(ROBOT, "manager", "path_follower_mode"):
                        ControlModoSegCam(modo_o_comando=1, numero_de_comando=0),
                    keys.slot_key(ROBOT, "pan_tilt", "control_entrada"):
                        ControlEntradaPT(slot_entrada_control_modos=5, slot_entrada_datos=20),
                }
                pubs = [zenoh.ext.declare_advanced_publisher(
                    attacker.session, key, cache=zenoh.ext.CacheConfig(1), publisher_detection=True,
                    sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=0.5)) for key in forged]
                try:
                    heard(attacker.session, marker, marks, b"ready")
                    for pub, value in zip(pubs, forged.values(), strict=True):
                        pub.put(msgspec.msgpack.encode(value))
                    heard(attacker.session, marker, marks, b"after the forged publishers")
                    # a late publisher is detected by its token and asked at once; give an admitted one time
                    threading.Event().wait(3.0)
                finally:
                    for pub in pubs:
                        pub.undeclare()
            assert "ABORT" not in [c["name"] for c in robot.commands()[mark:]], "the forged Abort reached the DSP"
            assert not [a for a in acks if a.routes.get("datos") == 20], "pan & tilt read the forged route"
            assert not [line for line in robot.launch.lines if "route drift" in line]
            # the legitimate twin: the GCS's hold makes the manager send the same command, which reaches the DSP
            reply = gcs.send(ROBOT, gri.Hold())
            assert reply.accepted, reply.reason
            wait_until(lambda: "ABORT" in [c["name"] for c in robot.commands()[mark:]], 30, "the hold's ABORT")
        finally:
            for sub in subs:
                sub.undeclare()


FORGED_ID = 2**31 - 1


@pytest.mark.timeout(420)
def test_gcs_survey_works_and_a_module_identity_cannot_request_a_trajectory(robot: Robot) -> None:
    """The RAL's survey request to the trajectory generator goes through the policy (the path reaches the DSP
    simulator); the vision identity's request on the same key is dropped by the router (never answered,
    never planned)."""
    statuses: list[TrajectoryStatus] = []
    surveys: list[DatosSegCam] = []
    orbits: list[DatosSegCam] = []
    marker = f"cromat/{ROBOT}/vision/marker"
    marks: list[bytes] = []
    with robot.client("gcs", name="gcs", link=[ROBOT], timeout_s=10.0) as gcs:
        s = gcs.session
        subs = [
            s.declare_subscriber(keys.slot_key(ROBOT, "trajectory", "status"), lambda x: statuses.append(
                msgspec.msgpack.decode(x.payload.to_bytes(), type=TrajectoryStatus))),
            s.declare_subscriber(keys.slot_key(ROBOT, "trajectory", "survey"), lambda x: surveys.append(
                msgspec.msgpack.decode(x.payload.to_bytes(), type=DatosSegCam))),
            s.declare_subscriber(keys.slot_key(ROBOT, "trajectory", "orbit"), lambda x: orbits.append(
                msgspec.msgpack.decode(x.payload.to_bytes(), type=DatosSegCam))),
            s.declare_subscriber(marker, lambda x: marks.append(x.payload.to_bytes())),
        ]
        try:
            state = gcs.state(ROBOT)
            wait_until(lambda: (st := gcs.state(ROBOT)).position is not None and st.home is not None, 30,
                       "the robot's position")
            home = gcs.state(ROBOT).home
            assert home is not None
            # the attack: a module identity asks the generator for an orbit, then a marker on its own key
            with robot.client("vision", name="intruder", timeout_s=5.0) as attacker:
                forged = TrajectoryRequest(request_id=FORGED_ID, orbit=OrbitRequest(
                    centre=Vertex(lat=home.lat, lon=home.lon), radius=40.0, height=20.0))
                heard(attacker.session, marker, marks, b"ready")
                attacker.session.put(keys.slot_key(ROBOT, "trajectory", "request"), msgspec.msgpack.encode(forged))
                heard(attacker.session, marker, marks, b"after the forged request")
            # the legitimate path: take off, then a survey from the GCS
            if not state.airborne:
                reply = gcs.send(ROBOT, gri.TakeOff(height=10.0))
                assert reply.accepted, reply.reason
                wait_until(lambda: bool(gcs.state(ROBOT).airborne), 120, "airborne")
            lat, lon = home.lat, home.lon
            polygon = [t.Vertex(lat=lat + a, lon=lon + b) for a, b in
                       ((0.0003, -0.0003), (0.0003, 0.0004), (0.0011, 0.0004), (0.0011, -0.0003))]
            mark = len(robot.commands())
            reply = gcs.send(ROBOT, t.Survey(polygon=polygon, height=25.0, overlap=0.1))
            assert reply.accepted, reply.reason
            wait_until(lambda: surveys, 30, "the generated survey path")
            planned = [(round(p.latitud, 4), round(p.longitud, 4)) for p in surveys[-1].puntos]

            def added() -> list[tuple[float, float]]:
                return [(round(c["fields"]["lat"], 4), round(c["fields"]["lon"], 4))
                        for c in robot.commands()[mark:] if c["name"] == "ADD_WAYPOINT"]
            wait_until(lambda: added() == planned, 120, "the survey's waypoints at the DSP simulator")
            # the status comes on its own key: no order with the path or the DSP record, so it is waited for
            wait_until(lambda: [st for st in statuses if st.accepted and st.kind == "survey"], 15,
                       "the generator's status accepting the survey")
            # the forged request was never answered nor planned (its answer would have come before the RAL's)
            assert not [st for st in statuses if st.request_id == FORGED_ID]
            assert orbits == []
            gcs.send(ROBOT, gri.Hold())
        finally:
            for sub in subs:
                sub.undeclare()


@pytest.mark.timeout(300)
def test_a_secure_robot_takes_part_in_fleet_allocation_and_a_module_identity_cannot_post_a_fleet_task(
        robot: Robot) -> None:
    """Fleet allocation under the robot's access policy (docs/fleet.md): the ground station's fleet task reaches
    the RAL, which bids, decides and flies its share (the target reaches the DSP simulator as an ADD_WAYPOINT, and
    the station sees the decision and the visit); the same task posted by the vision identity is dropped by the
    router: no robot ever answers it, nothing of it reaches the DSP."""
    with robot.client("gcs", name="gcs", link=[ROBOT], timeout_s=10.0) as gcs:
        view = FleetView(gcs.session)
        marker = f"cromat/{ROBOT}/vision/marker"
        marks: list[bytes] = []
        sub = gcs.session.declare_subscriber(marker, lambda x: marks.append(x.payload.to_bytes()))
        try:
            wait_until(lambda: (st := gcs.state(ROBOT)).position is not None and st.home is not None, 30,
                       "the robot's position")
            home = gcs.state(ROBOT).home
            assert home is not None
            if not gcs.state(ROBOT).airborne:
                reply = gcs.send(ROBOT, gri.TakeOff(height=10.0))
                assert reply.accepted, reply.reason
                wait_until(lambda: bool(gcs.state(ROBOT).airborne), 120, "airborne")
            mark = len(robot.commands())
            forged_at = (round(home.lat - 0.0004, 4), round(home.lon - 0.0004, 4))
            with robot.client("vision", name="intruder", timeout_s=5.0) as attacker:
                heard(attacker.session, marker, marks, b"ready")
                FleetView(attacker.session).post(FleetTask(id="forged", targets=[FleetTarget(
                    id="f0", lat=forged_at[0], lon=forged_at[1], alt=home.alt + 10.0)], posted_by="gcs"))
                heard(attacker.session, marker, marks, b"after the forged fleet task")
            target = (round(home.lat + 0.0003, 4), round(home.lon + 0.0002, 4))
            ground = robot.pki.with_name("pki-ground")  # the station signs with its own TLS identity
            view.post(FleetTask(id="secure_t1", targets=[FleetTarget(id="s0", lat=target[0], lon=target[1],
                                                                     alt=home.alt + 10.0)], posted_by="gcs"),
                      StationSigner.from_files(ground / "gcs.pem", ground / "gcs.key"))
            dec = view.wait(lambda: view.agreed("secure_t1", {ROBOT}), 30)
            assert dec is not None and dec.bidders == [ROBOT] and dec.routes[ROBOT] == ["s0"], view.decisions(
                "secure_t1")
            wait_until(lambda: view.visited("secure_t1") == {"s0"}, 120, "the fleet target visited")
            added = [(round(c["fields"]["lat"], 4), round(c["fields"]["lon"], 4))
                     for c in robot.commands()[mark:] if c["name"] == "ADD_WAYPOINT"]
            assert target in added, added
            # the forged task was posted before the real one: had it got through, the RAL would have answered it
            assert view.answered("forged") == set() and view.decisions("forged") == {}
            assert forged_at not in added, added
            gcs.send(ROBOT, gri.Hold())
        finally:
            sub.undeclare()
            view.close()
