"""Refusals explained (issue 12 item 5): the GCS names the cause of a refused connection, against a real mTLS
router with certificates made at test time (a second CA and an expired certificate included)."""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from bbcs.session import SessionConfig, TlsConfig
from bbcs.testing import Processes, free_port, wait_port
from cromat import certs
from ral.gcs.api import Gcs, Unreachable
from ral.gcs.diagnose import explain_no_reply


@pytest.fixture(scope="module")
def router(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, Path]]:
    tmp = tmp_path_factory.mktemp("diag")
    port = free_port()
    cfg = tmp / "router.json5"
    assert certs.main([str(tmp / "robot"), "--gcs", "gcs", "--module", "pan_tilt", "--robot", "uav1", "--acl",
                       str(cfg), "--listen", f"tls/127.0.0.1:{port}"]) == 0
    certs.make_leaf(tmp / "robot-ground", "old", days=-1, ca_dir=tmp / "robot-ca")
    assert certs.main([str(tmp / "other"), "--ca-name", "intruder-ca", "--gcs", "gcs", "--no-local"]) == 0
    procs = Processes()
    try:
        procs.start(["-m", "bbcs.router", "--config", str(cfg), "--listen", f"tls/127.0.0.1:{port}"],
                    stdout=subprocess.DEVNULL)
        wait_port(port)
        yield port, tmp
    finally:
        procs.stop_all()


def station(port: int, ca: Path, cert: Path | None) -> SessionConfig:
    tls = TlsConfig(root_ca=str(ca), cert=str(cert) if cert else None, key=str(cert.with_suffix(".key")) if cert
                    else None, mtls=cert is not None)
    return SessionConfig(connect=[f"tls/localhost:{port}"], tls=tls, connect_timeout_s=3.0)


@pytest.mark.parametrize(("case", "expected"), [
    ("no certificate", "TLS refused: no certificate"),
    ("station from another CA", "TLS refused: unknown CA: the router does not trust"),
    ("router from another CA", "TLS refused: unknown CA: the router's certificate is not signed"),
    ("expired", "TLS refused: expired"),
    ("nobody listening", "router unreachable"),
])
def test_the_gcs_names_why_it_was_refused(router: tuple[int, Path], case: str, expected: str) -> None:
    port, tmp = router
    ground, other = tmp / "robot-ground", tmp / "other-ground"
    cfg = {
        "no certificate": lambda: station(port, ground / "ca.pem", None),
        "station from another CA": lambda: station(port, ground / "ca.pem", other / "gcs.pem"),
        "router from another CA": lambda: station(port, other / "ca.pem", ground / "gcs.pem"),
        "expired": lambda: station(port, ground / "ca.pem", ground / "old.pem"),
        "nobody listening": lambda: station(free_port(), ground / "ca.pem", ground / "gcs.pem"),
    }[case]()
    with pytest.raises(Unreachable) as info:
        Gcs(cfg, timeout_s=2.0)
    assert f"): {expected}" in str(info.value), str(info.value)


def test_the_legitimate_station_connects(router: tuple[int, Path]) -> None:
    port, tmp = router
    with Gcs(station(port, tmp / "robot-ground" / "ca.pem", tmp / "robot-ground" / "gcs.pem"), timeout_s=2.0):
        pass


def test_no_reply_from_a_visible_robot_is_the_policy() -> None:
    assert explain_no_reply("uav1", True, "land").startswith("denied by policy: robot 'uav1' is up")
    assert explain_no_reply("uav1", False, "land").startswith("no answer from robot 'uav1' to land: the robot is not")


def test_a_certificate_not_yet_valid_is_not_called_expired(router: tuple[int, Path]) -> None:
    """Issue 32 item 9: a station whose clock is behind its certificate's start was told "expired"."""
    from datetime import UTC, datetime

    from ral.gcs.diagnose import diagnose_connect

    port, tmp = router
    cfg = station(port, tmp / "robot-ground" / "ca.pem", tmp / "robot-ground" / "gcs.pem")
    why = diagnose_connect(cfg, now=datetime(2001, 1, 1, tzinfo=UTC))
    assert why.startswith("TLS refused: not yet valid: this station's certificate"), why


def test_a_router_name_mismatch_is_not_called_unknown_ca(router: tuple[int, Path]) -> None:
    """Issue 32 item 9: a router whose certificate (from the right CA) names other hosts was reported as "unknown
    CA"; a real router presenting a certificate for elsewhere.invalid only, reached as localhost."""
    port, tmp = router
    other_port = free_port()
    certs.make_leaf(tmp / "elsewhere", "router", ["elsewhere.invalid"], ca_dir=tmp / "robot-ca")
    procs = Processes()
    try:
        procs.start(["-m", "bbcs.router", "--listen", f"tls/127.0.0.1:{other_port}", "--tls-ca",
                     str(tmp / "robot" / "ca.pem"), "--tls-cert", str(tmp / "elsewhere" / "router.pem"), "--tls-key",
                     str(tmp / "elsewhere" / "router.key")], stdout=subprocess.DEVNULL)
        wait_port(other_port)
        with pytest.raises(Unreachable) as info:
            Gcs(station(other_port, tmp / "robot-ground" / "ca.pem", tmp / "robot-ground" / "gcs.pem"), timeout_s=2.0)
        assert "): TLS refused: router name mismatch: the router's certificate does not name localhost" in str(
            info.value), str(info.value)
    finally:
        procs.stop_all()
