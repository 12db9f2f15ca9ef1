"""Issue 32 item 8, live: a station revoked while the robot's router runs is denied at once, without a restart.

``cromat router --revoked FILE`` watches the revoked list (``revoked.txt``); a name added there makes the router
write its policy again with that name denied everything and reopen its session on it. Real router, certificates
from ``cromat certs``, by effect: before, the station's GRI task request reaches the RAL's queryable and is
answered; after, neither its reconnected session nor a new one gets a request to the RAL (it is never asked), while
the other station's request, after the links came back, is answered. A file that is not the generated policy keeps
the running one, said in the log."""

from __future__ import annotations

import subprocess
import threading
from pathlib import Path

import pytest
import zenoh

from bbcs import acl
from bbcs.contracts import gri
from bbcs.errors import SessionError
from bbcs.router import revoke_in_config
from bbcs.session import SessionConfig, TlsConfig, open_session
from bbcs.testing import Processes, free_port, wait_port, wait_until
from cromat import certs

ROBOT = "uav1"


def test_a_station_revoked_while_the_router_runs_is_denied_at_once(tmp_path: Path) -> None:
    robot = tmp_path / "robot"
    ground = robot.with_name("robot-ground")
    assert certs.main([str(robot), "--gcs", "gcs", "--gcs", "gcs2", "--modules", "dsp", "--robot", ROBOT]) == 0
    port = free_port()
    cfg = tmp_path / "router.json5"
    acl.write(acl.router_config(listen=[f"tls/127.0.0.1:{port}"], ca=str(robot / "ca.pem"),
                                cert=str(robot / "router.pem"), key=str(robot / "router.key"), robot=ROBOT,
                                gcs=["gcs", "gcs2"], modules=["dsp"]), cfg)
    revoked = robot / "revoked.txt"  # what ``cromat certs --revoke`` writes
    assert not revoked.exists()

    def config(name: str, folder: Path) -> SessionConfig:
        return SessionConfig(connect=[f"tls/localhost:{port}"], tls=TlsConfig(
            root_ca=str(folder / "ca.pem"), cert=str(folder / f"{name}.pem"), key=str(folder / f"{name}.key")))

    def ask(session: zenoh.Session) -> bool:
        return any(r.ok is not None for r in session.get(gri.task_key(ROBOT), payload=b"task", timeout=2.0))

    procs = Processes()
    sessions: list[zenoh.Session] = []
    lines: list[str] = []
    try:
        router = procs.start(["-m", "bbcs.router", "--config", str(cfg), "--listen", f"tls/127.0.0.1:{port}",
                              "--revoked", str(revoked)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        threading.Thread(target=lambda: lines.extend(router.stdout), daemon=True).start()
        wait_port(port)
        ral = open_session(config("ral", robot))
        asked: list[str] = []

        def on_task(query: zenoh.Query) -> None:
            asked.append(str(query.key_expr))
            query.reply(query.key_expr, b"accepted")

        ral.declare_queryable(gri.task_key(ROBOT), on_task)
        station, thief = open_session(config("gcs", ground)), open_session(config("gcs2", ground))
        sessions += [ral, station, thief]
        wait_until(lambda: ask(thief), 20, "gcs2's request answered before its revocation")

        assert certs.main([str(robot), "--revoke", "gcs2"]) == 0  # while the router runs
        wait_until(lambda: any("revoked gcs2: policy reloaded" in line for line in lines), 20, "the reload")
        wait_until(lambda: ask(station), 30, "the other station answered again once the links are back")
        before = len(asked)
        assert not ask(thief), "the revoked station's reconnected session still reaches the RAL"
        try:
            fresh = open_session(config("gcs2", ground))
        except SessionError:  # refused at the link is as good
            fresh = None
        if fresh is not None:
            sessions.append(fresh)
            assert not ask(fresh)
        assert len(asked) == before, "the RAL's queryable was asked by the revoked station"
        print(f"\nrouter: {next(line for line in lines if 'revoked gcs2' in line).strip()}")
    finally:
        for s in sessions:
            s.close()
        procs.stop_all()


def test_a_file_that_is_not_the_generated_policy_is_refused(tmp_path: Path) -> None:
    (tmp_path / "plain.json5").write_text('{ "mode": "router" }\n')
    with pytest.raises(ValueError, match="no access policy"):
        revoke_in_config(tmp_path / "plain.json5", ["gcs2"])
    (tmp_path / "bad.json5").write_text("{ mode: router }\n")
    with pytest.raises(ValueError, match="not the generated JSON policy"):
        revoke_in_config(tmp_path / "bad.json5", ["gcs2"])
    assert not list(tmp_path.glob("*.live.json5"))
