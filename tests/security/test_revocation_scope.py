"""Issue 32 item 8: revocation reaches the routers, and a signed fleet task names the robots it is for.

* A revoked ground station still commanded the robot through the GRI: the routers' mutual TLS checks no CRL (no
  such setting in Zenoh), so ``cromat certs --revoke`` also writes the revoked names (``revoked.txt``) and the
  robot's router config denies them every message (bbcs/acl.py). Against a real router with that config and
  certificates from ``cromat certs``: the revoked station's task request never reaches the RAL's queryable (by
  effect: it is never asked), nor does it receive the robot's state; the other station's request is answered. A
  revoked name is never issued again.
* A captured, still-valid signed fleet task was flown by a robot that never saw it: the task now names its robots
  inside the signed bytes and a robot's gate refuses one that does not name it (NotForThisRobot), with the real
  certificates and the RAL's fleet gate.
"""

from __future__ import annotations

import subprocess
import threading
import time
from pathlib import Path

import pytest
import zenoh

from bbcs import acl
from bbcs.contracts import gri
from bbcs.contracts.fleet import FleetTarget, FleetTask
from bbcs.errors import SessionError
from bbcs.session import SessionConfig, TlsConfig, open_session
from bbcs.signing import FleetTrust, StationSigner
from bbcs.testing import Processes, free_port, wait_port, wait_until
from cromat import certs
from ral.fleet import TaskGate

ROBOT = "uav1"
R = f"cromat/{ROBOT}"


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A robot folder and its ground folder with two stations, gcs2 revoked (``cromat certs --revoke``)."""
    robot = tmp_path_factory.mktemp("revocation") / "robot"
    assert certs.main([str(robot), "--gcs", "gcs", "--gcs", "gcs2", "--modules", "dsp", "--robot", ROBOT]) == 0
    assert certs.main([str(robot), "--revoke", "gcs2"]) == 0
    return robot, robot.with_name("robot-ground")


def test_revoke_writes_the_names_and_a_revoked_name_is_never_issued_again(pki: tuple[Path, Path],
                                                                           tmp_path: Path) -> None:
    robot, ground = pki
    for folder in (robot, ground, robot.with_name("robot-ca")):
        assert certs.revoked_names(folder) == ["gcs2"]
    again = [str(robot), "--ca", str(robot.with_name("robot-ca")), "--ground", str(tmp_path / "g"), "--no-local",
             "--modules", "x", "--robot", ROBOT]
    assert certs.main([*again, "--gcs", "gcs2"]) == 2
    assert not (tmp_path / "g" / "gcs2.pem").exists()


def test_a_revoked_station_gets_nothing_through_the_router(pki: tuple[Path, Path], tmp_path: Path) -> None:
    robot, ground = pki
    port = free_port()
    cfg = acl.router_config(listen=[f"tls/127.0.0.1:{port}"], ca=str(robot / "ca.pem"), cert=str(robot / "router.pem"),
                            key=str(robot / "router.key"), robot=ROBOT, gcs=["gcs", "gcs2"], modules=["dsp"],
                            revoked=certs.revoked_names(robot))
    acl.write(cfg, tmp_path / "router.json5")

    def config(name: str, folder: Path) -> SessionConfig:
        return SessionConfig(connect=[f"tls/localhost:{port}"], tls=TlsConfig(
            root_ca=str(folder / "ca.pem"), cert=str(folder / f"{name}.pem"), key=str(folder / f"{name}.key")))

    procs = Processes()
    sessions: list[zenoh.Session] = []
    try:
        procs.start(["-m", "bbcs.router", "--config", str(tmp_path / "router.json5"), "--listen",
                     f"tls/127.0.0.1:{port}"], stdout=subprocess.DEVNULL)
        wait_port(port)
        ral = open_session(config("ral", robot))
        sessions.append(ral)
        asked: list[str] = []

        def on_task(query: zenoh.Query) -> None:
            asked.append(str(query.selector))
            query.reply(query.key_expr, b"accepted")

        queryable = ral.declare_queryable(gri.task_key(ROBOT), on_task)
        try:
            stolen = open_session(config("gcs2", ground))
        except SessionError:  # refused at the link is as good: nothing of it reaches the robot
            stolen = None
        else:
            sessions.append(stolen)
            seen = threading.Event()
            stolen.declare_subscriber(f"{R}/@ral/state", lambda _s: seen.set())
            assert [r for r in stolen.get(gri.task_key(ROBOT), timeout=3.0) if r.ok is not None] == []
        genuine = open_session(config("gcs", ground))
        sessions.append(genuine)
        wait_until(lambda: any(r.ok is not None for r in genuine.get(gri.task_key(ROBOT), timeout=5.0)), 30,
                   "the genuine station's task answered")
        assert len(asked) >= 1 and all(a.startswith(gri.task_key(ROBOT)) for a in asked)
        n = len(asked)
        if stolen is not None:
            assert [r for r in stolen.get(gri.task_key(ROBOT), timeout=3.0) if r.ok is not None] == []
            assert len(asked) == n, "the revoked station's request reached the RAL"
            ral.put(f"{R}/@ral/state", b"state")
            time.sleep(1.0)  # a wrongly delivered state would arrive in well under a second on loopback
            assert not seen.is_set(), "the revoked station still reads the robot"
        queryable.undeclare()
    finally:
        for s in sessions:
            s.close()
        procs.stop_all()


def test_a_captured_task_is_not_flown_by_a_robot_it_does_not_name(pki: tuple[Path, Path]) -> None:
    robot, ground = pki
    trust = FleetTrust.from_files(robot / "ca.pem", ["gcs", "gcs2"], robot / "crl.pem")
    signer = StationSigner.from_files(ground / "gcs.pem", ground / "gcs.key")
    now = time.time()
    task = signer.sign(FleetTask(id="t1", targets=[FleetTarget(id="a", lat=37.41, lon=-6.0, alt=40.0)],
                                 robots=["uav1", "uav2"]), now=now)
    assert TaskGate(trust, lambda: now, robot="uav1").admit(task, "a peer")
    newcomer = TaskGate(trust, lambda: now, robot="uav3")  # a robot that joined (or was built) after the post
    assert not newcomer.admit(task, "a peer")
    assert newcomer.refused == {"NotForThisRobot": 1}
    forged = FleetTask(**{f: getattr(task, f) for f in task.__struct_fields__} | {"robots": ["uav1", "uav3"]})
    assert not newcomer.admit(forged, "a peer")  # naming itself breaks the station's signature
    assert newcomer.refused["BadSignature"] == 1
    stolen = StationSigner.from_files(ground / "gcs2.pem", ground / "gcs2.key").sign(
        FleetTask(id="t2", targets=task.targets, robots=["uav1"]), now=now)
    assert not TaskGate(trust, lambda: now, robot="uav1").admit(stolen, "a peer")  # revoked: the CRL still holds
