import json
import subprocess
import sys
import threading

import pytest
import zenoh

from bbcs.errors import SessionError
from bbcs.session import SessionConfig, TlsConfig, local_client, open_session, zenoh_config
from bbcs.testing import ROOT, Processes, child_env, free_port, start_router


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


_RUNTIME_PROBE = """
import glob, os, sys, time
from bbcs.session import local_client, open_session
s = open_session(local_client(int(sys.argv[1])), module=sys.argv[2] == "module")
p = s.declare_publisher("probe/rx")
sub = s.declare_subscriber("probe/rx", lambda _s: None)
for _ in range(50):
    p.put(b"1")
time.sleep(0.3)
comms = [open(f).read().strip() for f in glob.glob(f"/proc/{os.getpid()}/task/*/comm")]
print(sum(1 for c in comms if c.startswith("rx-")), os.environ.get("ZENOH_RUNTIME", "-"))
s.close()
"""


@pytest.mark.parametrize("kind, operator_setting, rx_threads", [
    ("module", None, 1), ("module", "(rx: (worker_threads: 3))", 3), ("tool", None, 2)])
def test_a_module_process_receives_on_one_zenoh_thread_unless_the_operator_says_otherwise(
        kind: str, operator_setting: str | None, rx_threads: int) -> None:
    """bbcs.session.MODULE_RUNTIME, by effect: the process's Zenoh receive threads (named ``rx-N``), and the
    variable gone again after the open (a router this process starts must not inherit it). A process that is not a
    module (a tool, a ground station, a test harness with many sessions) keeps Zenoh's default of two."""
    procs = Processes()
    try:
        port = start_router(procs)
        env = child_env()
        env.pop("ZENOH_RUNTIME", None)
        if operator_setting is not None:
            env["ZENOH_RUNTIME"] = operator_setting
        out = subprocess.run([sys.executable, "-c", _RUNTIME_PROBE, str(port), kind], env=env, capture_output=True,
                             text=True, timeout=60, cwd=str(ROOT))
        assert out.returncode == 0, out.stderr
        count, left = out.stdout.strip().split(" ", 1)
        assert int(count) == rx_threads
        assert left == (operator_setting or "-")
    finally:
        procs.stop_all()
