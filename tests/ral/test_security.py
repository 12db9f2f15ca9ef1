"""The security matrix against a real robot router process with mTLS and the generated access policy.

Certificates are made in tmp_path by ``cromat certs``; every client connects over ``tls/127.0.0.1``.
"""

from __future__ import annotations

import subprocess
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from bbcs import keys
from bbcs.context import ModuleContext
from bbcs.contracts import gri, mri
from bbcs.session import SessionConfig, TlsConfig, open_session
from bbcs.testing import Processes, free_port, wait_port, wait_until
from cromat import certs
from ral.gcs.api import Gcs, NoReply, Unreachable
from ral.module import Ral

sys.path.insert(0, str(Path(__file__).resolve().parent))
from standin import ROBOT, StandIn  # noqa: E402


@dataclass
class Secure:
    port: int
    pki: Path
    other: Path
    manager: StandIn
    ral: Ral

    def client(self, name: str | None, pki: Path | None = None, connect_timeout_s: float = 10.0) -> SessionConfig:
        """A TLS client; the generous connect deadline is for a loaded machine (refused ones pass a short one)."""
        pki = pki or self.pki
        if name == "gcs":  # ground-station pairs are written to the ground folder, never the robot's (issue 12)
            pki = pki.with_name(pki.name + "-ground")
        tls = TlsConfig(
            root_ca=str(pki / "ca.pem"),
            cert=str(pki / f"{name}.pem") if name else None,
            key=str(pki / f"{name}.key") if name else None,
            mtls=name is not None,
        )
        return SessionConfig(connect=[f"tls/localhost:{self.port}"], tls=tls, connect_timeout_s=connect_timeout_s)


@pytest.fixture(scope="module")
def secure(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Secure]:
    tmp = tmp_path_factory.mktemp("pki")
    port = free_port()
    pki, other = tmp / "robot", tmp / "other"
    cfg = tmp / "router.json5"
    assert (
        certs.main(
            [
                str(pki),
                "--gcs",
                "gcs",
                "--module",
                "pan_tilt",
                "--robot",
                ROBOT,
                "--acl",
                str(cfg),
                "--listen",
                f"tls/127.0.0.1:{port}",
            ]
        )
        == 0
    )
    assert certs.main([str(other), "--ca-name", "intruder-ca", "--gcs", "gcs", "--no-local"]) == 0
    procs = Processes()
    manager_session = None
    ral = thread = manager = None
    try:
        procs.start(
            ["-m", "bbcs.router", "--config", str(cfg), "--listen", f"tls/127.0.0.1:{port}"],
            stdout=subprocess.DEVNULL,
        )
        wait_port(port)
        probe = Secure(port, pki, other, None, None)  # type: ignore[arg-type]
        manager_session = open_session(probe.client("manager"))
        manager = StandIn(manager_session)
        manager.start()
        ral = Ral(
            ModuleContext(
                robot=ROBOT, module="ral", bus=probe.client("ral"), params={"state_period_s": "0.1"}
            )
        )
        thread = threading.Thread(target=ral.run, daemon=True)
        thread.start()
        with Gcs(probe.client("gcs"), timeout_s=10.0) as gcs:  # the RAL serving, its task list known
            wait_until(lambda: gcs.robots() == [ROBOT], 30, "the RAL alive")
            wait_until(lambda: bool(gcs.state(ROBOT).available), 30, "the RAL's task list")
        yield Secure(port, pki, other, manager, ral)
    finally:
        if ral is not None and thread is not None:
            ral.request_stop()
            thread.join(10)
        if manager is not None:
            manager.close()
        if manager_session is not None:
            manager_session.close()
        procs.stop_all()


def test_no_certificate_is_refused(secure: Secure) -> None:
    with pytest.raises(Unreachable, match="refused|reach"):
        Gcs(secure.client(None, connect_timeout_s=3.0), timeout_s=2.0)


def test_certificate_from_another_ca_is_refused(secure: Secure) -> None:
    cfg = secure.client("gcs", secure.other)
    cfg = SessionConfig(
        connect=cfg.connect,
        connect_timeout_s=3.0,
        tls=TlsConfig(
            root_ca=str(secure.pki / "ca.pem"),
            cert=str(secure.other.with_name("other-ground") / "gcs.pem"),
            key=str(secure.other.with_name("other-ground") / "gcs.key"),
        ),
    )
    with pytest.raises(Unreachable):
        Gcs(cfg, timeout_s=2.0)


def test_gcs_identity_submits_tasks(secure: Secure) -> None:
    with Gcs(secure.client("gcs"), timeout_s=10.0) as gcs:
        reply = gcs.send(ROBOT, gri.Hold())
        assert reply.accepted, reply.reason
        assert secure.manager.set_tasks()[-1] == mri.SetTask(name="hold", params=gri.Hold(), origin="gcs")


def test_module_identity_submitting_a_task_is_denied_and_robot_unaffected(secure: Secure) -> None:
    before = len(secure.manager.requests)
    tasks_before = secure.manager.book.active()  # the task book (the stand-in manager's, as on a robot)
    with Gcs(secure.client("pan_tilt"), timeout_s=2.0) as module:
        with pytest.raises(NoReply, match="may not submit"):
            module.send(ROBOT, gri.Land())
        with pytest.raises(NoReply):
            module.route(ROBOT, "pan_tilt", "datos", 3)
    with Gcs(secure.client("gcs"), timeout_s=10.0) as gcs:
        # a request through the RAL's one worker queue after the denied ones, changing nothing: once it is
        # answered, anything that had got through has been handled (and sent to the manager) too
        assert not gcs.send(ROBOT, gri.Cancel(task_type="no_such_type")).accepted
        assert len(secure.manager.requests) == before
        assert secure.manager.book.active() == tasks_before
        assert gcs.state(ROBOT).robot == ROBOT


def test_module_writes_only_its_own_slots(secure: Secure) -> None:
    got: list[str] = []
    with Gcs(secure.client("gcs")) as reader:
        sub = reader.session.declare_subscriber(f"cromat/{ROBOT}/*/*", lambda s: got.append(str(s.key_expr)))
        module = open_session(secure.client("pan_tilt"))
        try:
            own = keys.slot_key(ROBOT, "pan_tilt", "error")
            foreign = keys.slot_key(ROBOT, "path_follower", "control_modo")
            wait_until(
                lambda: (module.put(foreign, b"x"), module.put(own, b"x"), own in got)[-1],
                what="own slot delivered",
            )
            assert foreign not in got
        finally:
            sub.undeclare()
            module.close()


@pytest.mark.parametrize("identity", ["gcs", "pan_tilt", "ral", "manager"])
def test_every_identity_reads_state(secure: Secure, identity: str) -> None:
    with Gcs(secure.client(identity), timeout_s=10.0) as station:
        state = station.state(ROBOT)
        assert state.robot == ROBOT and state.available
        assert station.robots() == [ROBOT]
