"""Issue 32 item 9: ``cromat bus pub`` reaches a TLS router with its own certificate and says when the router
dropped what it put. Against a real robot router with the generated policy, certificates from ``cromat certs``:
the ``key`` argument (the slot) no longer overwrites ``--key`` (the private key), so the tool connects; a put the
policy lets through is reported delivered (exit 0), one it drops is reported dropped (exit 1), never "published".
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from bbcs.testing import Processes, free_port, wait_port
from cromat.tools import bus_cli

ROBOT = "uav1"


@pytest.fixture(scope="module")
def router(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, Path]]:
    from cromat import certs

    tmp = tmp_path_factory.mktemp("tools_tls")
    port = free_port()
    pki, cfg = tmp / "robot", tmp / "router.json5"
    assert certs.main([str(pki), "--gcs", "gcs", "--modules", "pan_tilt,vision", "--robot", ROBOT, "--acl", str(cfg),
                       "--listen", f"tls/127.0.0.1:{port}"]) == 0
    procs = Processes()
    try:
        procs.start(["-m", "bbcs.router", "--config", str(cfg), "--listen", f"tls/127.0.0.1:{port}"],
                    stdout=subprocess.DEVNULL)
        wait_port(port)
        yield port, pki
    finally:
        procs.stop_all()


def _pub(port: int, pki: Path, identity: str, key: str, capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    capsys.readouterr()
    code = bus_cli.main(["--connect", f"tls/localhost:{port}", "--ca", str(pki / "ca.pem"), "--cert",
                         str(pki / f"{identity}.pem"), "--key", str(pki / f"{identity}.key"), "--timeout", "10",
                         "pub", key, '{"ref_pan": 10.0}', "--type", "bbcs.contracts.pan_tilt:DatosPT"])
    out, err = capsys.readouterr()
    return code, out, err


def test_pub_connects_over_tls_and_reports_what_the_router_delivered(router: tuple[int, Path],
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    port, pki = router
    code, out, err = _pub(port, pki, "pan_tilt", f"{ROBOT}/pan_tilt/test_out", capsys)
    assert code == 0, err
    assert f"published 1 x bbcs.contracts.pan_tilt:DatosPT on cromat/{ROBOT}/pan_tilt/test_out (the router " \
           "delivered 1)" in out


def test_pub_says_when_the_router_dropped_everything(router: tuple[int, Path],
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    port, pki = router
    code, out, err = _pub(port, pki, "vision", f"{ROBOT}/pan_tilt/test_out", capsys)  # not vision's slot
    assert code == 1
    assert "published" not in out
    assert f"the router delivered none of the 1 put on cromat/{ROBOT}/pan_tilt/test_out" in err
