"""Zenoh's shared memory on a secured robot: payloads of 3 KB and more would otherwise travel between processes of the
same host through ``/dev/shm`` segments (Zenoh 1.10's transport optimisation, on by default and over TLS links too),
which any process of the same user can open: a compromised module could read, or rewrite, another module's payload
around the TLS link and the access policy. A secured session (``SessionConfig.tls``) and the secured router config
turn it off (bbcs/session.py, bbcs/acl.py).

The attack is made for real: a 32 KB payload carrying a random marker goes between two peers linked directly, and
the attacker, a reader of ``/dev/shm`` under the same user, looks for the marker there. Control case: two plain peers
(shared memory on, Zenoh's default) do leave it there, so the attack works where shared memory is used.
"""

from __future__ import annotations

import secrets
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from bbcs import acl
from bbcs.session import SessionConfig, TlsConfig, open_session, zenoh_config
from bbcs.testing import free_port, wait_until
from cromat import certs

SHM = Path("/dev/shm")


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("shm") / "pki"
    assert certs.main([str(folder), "--gcs", "gcs", "--modules", "dsp,vision", "--robot", "uav1"]) == 0
    return folder


def _peers(listener: SessionConfig, dialer: SessionConfig) -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    a = open_session(listener)
    try:
        b = open_session(dialer)
        try:
            yield a, b
        finally:
            b.close()
    finally:
        a.close()


def _leaked(marker: bytes) -> bool:
    """The attacker: every Zenoh segment in /dev/shm it can open (same user), searched for the marker."""
    for seg in SHM.glob("*.zenoh"):
        try:
            if marker in seg.read_bytes():
                return True
        except OSError:
            continue
    return False


def _send_and_look(listener: SessionConfig, dialer: SessionConfig, rounds: int = 10) -> tuple[bool, bool]:
    """Stream 32 KB payloads carrying a fresh marker from the dialer to the listener, 200 a round, the attacker
    looking after each round while the receiver still holds them; (all delivered, found in /dev/shm).

    Rounds, because Zenoh sets its shared memory up lazily: the first large puts take the link itself."""
    marker = secrets.token_bytes(24)
    payload = marker * (32_000 // len(marker))
    cond = threading.Condition()
    held: list[zenoh.ZBytes] = []  # as a module's input queue holds its samples until its loop takes them

    def receive(sample: zenoh.Sample) -> None:
        with cond:
            held.append(sample.payload)
            cond.notify_all()

    for a, b in _peers(listener, dialer):
        sub = a.declare_subscriber("shm/probe", receive)
        pub = b.declare_publisher("shm/probe", reliability=zenoh.Reliability.RELIABLE,
                                  congestion_control=zenoh.CongestionControl.BLOCK)
        try:
            wait_until(lambda p=pub: p.matching_status.matching, 10, "the probe's subscription at the dialer")
            for _ in range(rounds):
                for _ in range(200):
                    pub.put(payload)
                with cond:
                    delivered = cond.wait_for(lambda: len(held) == 200, 10)
                    intact = all(p.to_bytes() == payload for p in held)
                if not (delivered and intact):
                    return False, _leaked(marker)
                if _leaked(marker):  # while the receiver holds them: Zenoh clears a buffer once it is released
                    return True, True
                with cond:
                    held.clear()
            return True, False
        finally:
            pub.undeclare()
            sub.undeclare()
    raise AssertionError("unreachable")


def _tls(pki: Path, who: str) -> TlsConfig:
    return TlsConfig(root_ca=str(pki / "ca.pem"), cert=str(pki / f"{who}.pem"), key=str(pki / f"{who}.key"),
                     verify_name=False)


def test_control_plain_peers_leave_a_payload_readable_in_shared_memory() -> None:
    port = free_port()
    listener = SessionConfig(mode="peer", listen=[f"tcp/127.0.0.1:{port}"], connect=[])
    dialer = SessionConfig(mode="peer", listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    delivered, found = _send_and_look(listener, dialer)
    assert delivered
    assert found, "Zenoh no longer puts 32 KB payloads in shared memory: this file's premise needs a new look"


def test_secured_peers_keep_payloads_out_of_shared_memory(pki: Path) -> None:
    port = free_port()
    listener = SessionConfig(mode="peer", listen=[f"tls/127.0.0.1:{port}"], connect=[], tls=_tls(pki, "dsp"))
    dialer = SessionConfig(mode="peer", listen=[], connect=[f"tls/127.0.0.1:{port}"], tls=_tls(pki, "vision"))
    delivered, found = _send_and_look(listener, dialer)
    assert delivered
    assert not found, "a secured link's payload could be read from /dev/shm by any process of the same user"


def test_every_secured_config_turns_shared_memory_off(pki: Path) -> None:
    client = zenoh_config(SessionConfig(connect=["tls/127.0.0.1:7447"], tls=_tls(pki, "dsp")))
    assert client.get_json("transport/shared_memory/enabled") == "false"
    plain = zenoh_config(SessionConfig(connect=["tcp/127.0.0.1:7447"]))
    assert plain.get_json("transport/shared_memory/enabled") == "true"  # a plain robot keeps Zenoh's speed-up
    router = acl.router_config(listen=["tls/127.0.0.1:7447"], ca="ca.pem", cert="router.pem", key="router.key",
                               robot="uav1", gcs=["gcs"], modules=["dsp"])
    assert router["transport"]["shared_memory"] == {"enabled": False}
    hub = acl.hub_config(listen=["tls/127.0.0.1:7447"], ca="ca.pem", cert="hub.pem", key="hub.key", gcs=["gcs"],
                         robots=["uav1"])
    assert hub["transport"]["shared_memory"] == {"enabled": False}
