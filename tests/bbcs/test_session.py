import json
import threading

import pytest
import zenoh

from bbcs.errors import SessionError
from bbcs.session import SessionConfig, TlsConfig, local_client, open_session, zenoh_config
from bbcs.testing import free_port


def _get(conf: zenoh.Config, key: str):
    return json.loads(conf.get_json(key))


def test_client_config_is_explicit_and_scouting_off():
    conf = zenoh_config(local_client(7999))
    assert _get(conf, "mode") == "client"
    assert _get(conf, "connect/endpoints") == ["tcp/127.0.0.1:7999"]
    assert _get(conf, "listen/endpoints") == []
    assert _get(conf, "scouting/multicast/enabled") is False


def test_tls_files_go_to_the_side_that_uses_them():
    tls = TlsConfig(root_ca="/pki/ca.pem", cert="/pki/gcs.pem", key="/pki/gcs.key")
    client = zenoh_config(SessionConfig(connect=["tls/127.0.0.1:7447"], tls=tls))
    assert _get(client, "transport/link/tls/connect_certificate") == "/pki/gcs.pem"
    assert _get(client, "transport/link/tls/enable_mtls") is True
    router = zenoh_config(SessionConfig(mode="router", listen=["tls/127.0.0.1:7447"], connect=[], tls=tls))
    assert _get(router, "transport/link/tls/listen_private_key") == "/pki/gcs.key"


def test_unreachable_router_is_a_clear_error():
    port = free_port()
    with pytest.raises(SessionError, match=f"tcp/127.0.0.1:{port}"):
        open_session(SessionConfig(connect=[f"tcp/127.0.0.1:{port}"], connect_timeout_s=0.3))


def test_missing_config_file_is_a_clear_error(tmp_path):
    with pytest.raises(SessionError, match="nope.json5"):
        zenoh_config(SessionConfig(config_file=str(tmp_path / "nope.json5")))


def test_two_clients_talk_through_the_router(sessions):
    a, b = sessions(), sessions()
    got = threading.Event()
    sub = b.declare_subscriber("cromat/t/x/y", lambda s: got.set())
    try:
        pub = a.declare_publisher("cromat/t/x/y")
        for _ in range(200):  # the subscription reaches the router asynchronously: retry until it is there
            pub.put(b"1")
            if got.wait(0.05):
                break
        assert got.is_set()
        pub.undeclare()
    finally:
        sub.undeclare()
