"""The router logs refused links and denied messages, counted and rate limited (issue 12 item 5)."""

from __future__ import annotations

import subprocess
import threading
from pathlib import Path

from bbcs.errors import SessionError
from bbcs.router_audit import LogReader, Refusal, RefusalLog, parse
from bbcs.session import SessionConfig, TlsConfig, open_session
from bbcs.testing import Processes, free_port, wait_until
from cromat import certs

DENIED = ("\x1b[2m2026-11-23T17:12:15.694775Z\x1b[0m TRACE  rx-1 ThreadId(10) zenoh::net::routing::interceptor::"
          "access_control: 7444 on Interface(lo)+CertCommonName(vision)+Transport(Tls)+7444 is unauthorized to Put "
          "(ingress) on cromat/uav1/pan_tilt/x")
NO_CERT = "2026-11-23T17:12:16.224446Z  WARN acc-0 ThreadId(06) zenoh_link_tls::unicast: peer sent no certificates."


def test_zenoh_log_lines_become_refusals() -> None:
    assert parse(DENIED) == Refusal("denied", "vision may not put on cromat/uav1/pan_tilt/x (ingress)")
    assert parse(NO_CERT) == Refusal("link refused", "peer sent no certificates")
    assert parse("2026-11-23T17:12:15Z WARN zenoh_link_tls::unicast: tls handshake eof. Hint") is None
    assert parse(DENIED.replace("unauthorized", "authorized")) is None


ACL = "2026-11-23T19:14:14.54Z TRACE  rx-0 ThreadId(9) zenoh::net::routing::interceptor::access_control: "
WHO = "2215 on Interface(lo)+CertCommonName(vision)+Transport(Tls)+2215"
KINDS = ["Query", "Reply", "Put", "Delete", "Declare/Undeclare Subscriber", "Declare/Undeclare Queryable",
         "Declare/Undeclare Liveliness Token", "Liveliness Query", "Declare Liveliness Subscriber"]


def test_permission_tables_are_not_refusals_and_cached_denials_are_named_by_cn() -> None:
    """A declared key expression fills a table of 9 permission lines (denied kinds included): nothing was refused.
    A real denial after it, in the same thread and on the same key, is one; a cached one names the CN."""
    key = "cromat/uav1/manager/pan_tilt_mode"
    table = [ACL + f"ACL (ingress): caching permissions for `{key}` ..."] + [
        ACL + f"{WHO} is {'authorized' if k == 'Declare/Undeclare Subscriber' else 'unauthorized'} to {k} "
              f"(ingress) on {key}" for k in KINDS]
    real = ACL + f"{WHO} is unauthorized to Put (ingress) on {key}"
    cached = ACL + f"Using cached result: 2215 is unauthorized to Put (ingress) on {key}"
    reader = LogReader()
    assert [reader.feed(line) for line in table] == [None] * 10
    assert reader.feed(real) == Refusal("denied", f"vision may not put on {key} (ingress)")
    assert reader.feed(cached) == Refusal("denied", f"vision may not put on {key} (ingress)")
    assert reader.feed(cached.replace("unauthorized", "authorized")) is None


def test_counted_and_rate_limited_with_a_summary() -> None:
    now = [0.0]
    log = RefusalLog(clock=lambda: now[0], period_s=10.0, burst=2)
    r = Refusal("denied", "vision may not put on k (ingress)")
    shown = [log.note(r) for _ in range(5)]
    assert [len(s) for s in shown] == [1, 1, 0, 0, 0] and "(2 denied so far)" in shown[1][0]
    now[0] = 11.0
    lines = log.note(r)
    assert lines[0] == "cromat router: 3 more denied not shown in the last 10 s"
    assert log.note(Refusal("link refused", "peer sent no certificates"))  # another kind has its own budget
    assert lines[1].endswith("(6 denied so far)") and log.counts["denied"] == 6 and log.counts["link refused"] == 1


def test_a_real_router_logs_what_it_refused(tmp_path: Path) -> None:
    port = free_port()
    cfg = tmp_path / "router.json5"
    assert certs.main([str(tmp_path / "pki"), "--gcs", "gcs", "--module", "vision", "--robot", "uav1", "--acl",
                       str(cfg), "--listen", f"tls/127.0.0.1:{port}"]) == 0
    procs = Processes()
    lines: list[str] = []
    try:
        router = procs.start(["-m", "bbcs.router", "--config", str(cfg), "--listen", f"tls/127.0.0.1:{port}",
                              "--log-refusals"], stdout=subprocess.PIPE, text=True)

        def read() -> None:
            for line in router.stdout:
                lines.append(line.rstrip())
        threading.Thread(target=read, daemon=True).start()
        wait_until(lambda: any("listening on" in line for line in lines), 20, "the router's ready line")
        pki = tmp_path / "pki"

        def client(name: str | None) -> SessionConfig:
            tls = TlsConfig(root_ca=str(pki / "ca.pem"), cert=str(pki / f"{name}.pem") if name else None,
                            key=str(pki / f"{name}.key") if name else None, mtls=name is not None)
            return SessionConfig(connect=[f"tls/localhost:{port}"], tls=tls, connect_timeout_s=2.0)

        s = open_session(client("vision"))
        try:
            for _ in range(20):
                s.put("cromat/uav1/pan_tilt/mode", b"forged")
            wait_until(lambda: any("denied: vision may not put on cromat/uav1/pan_tilt/mode" in line
                                   for line in lines), 20, "the denied put in the router's log")
        finally:
            s.close()
        try:
            open_session(client(None)).close()
        except SessionError:
            pass
        try:
            wait_until(lambda: any("link refused: peer sent no certificates" in line for line in lines), 20,
                       "the refused link in the router's log")
        except AssertionError:
            raise AssertionError("\n".join(lines)) from None
        denied = [line for line in lines if " denied: " in line]
        assert 1 <= len(denied) <= 5  # 20 denied puts, at most `burst` lines
        assert not any("TRACE" in line for line in lines)  # Zenoh's own trace lines are not passed through
        router.terminate()  # and it stops at once (Zenoh's last trace lines must not block on the pipe)
        assert router.wait(30) == 0
    finally:
        procs.stop_all()
