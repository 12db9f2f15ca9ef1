"""``module_manager.direct_links``: which pairs of processes have a direct TCP link, read from the kernel's socket
tables; and a launch with ``links = "peers"`` says "all modules up" only once every pair of modules has linked."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from bbcs.contracts import mri
from bbcs.testing import wait_until
from module_manager.direct_links import tcp_ports, unlinked_pairs, verdict

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch_support import Launch, write_manifest  # noqa: E402

CONNECT = ("import socket, sys; s = socket.create_connection(('127.0.0.1', int(sys.argv[1]))); "
           "print('in', flush=True); sys.stdin.read()")
IDLE = "import sys; print('in', flush=True); sys.stdin.read()"


def child(code: str, *args: str) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", code, *args], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout is not None and proc.stdout.readline() == "in\n"
    return proc


def test_a_connection_to_a_listening_port_links_two_processes_and_nothing_else_does():
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]
        linked, idle = child(CONNECT, str(port)), child(IDLE)
        try:
            conn, _ = server.accept()
            with conn:
                listening, _ = tcp_ports(os.getpid())
                assert port in listening
                assert port in tcp_ports(linked.pid)[1]
                pids = {"us": os.getpid(), "linked": linked.pid, "idle": idle.pid}
                assert unlinked_pairs(pids) == [("idle", "linked"), ("idle", "us")]
        finally:
            for proc in (linked, idle):
                proc.kill()
                proc.wait(10)
                proc.stdin.close()
                proc.stdout.close()
    assert tcp_ports(linked.pid) == (set(), set()), "a process that is gone has no sockets"


def test_the_launch_waits_for_unlinked_pairs_then_names_them():
    apart = [("ral", "pan_tilt")]
    assert verdict(apart, 0.0, 30.0) is None
    assert verdict(apart, 29.9, 30.0) is None
    assert verdict(apart, 30.0, 30.0) == apart, "up at last, naming the pair still apart"
    assert verdict([], 0.0, 30.0) == [], "every pair linked: said up at once"


def peers(text: str) -> str:
    return text.replace('listen = ["tcp/127.0.0.1:{port:router}"]',
                        'listen = ["tcp/127.0.0.1:{port:router}"]\nlinks = "peers"')


def modules(session) -> dict[str, mri.ModuleStatus]:
    reply = mri.call(session, "r1", "modules", mri.ListModules(), 20.0)
    assert reply.ok
    return {m.name: m for m in reply.data.modules}


@pytest.fixture(scope="module")
def peer_launch(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Launch]:
    """One ``links = "peers"`` launch for the two tests below: the first reads its start-up, the second (after it
    in this file) then kills and restarts a module of it."""
    tmp = tmp_path_factory.mktemp("peers")
    la = Launch(write_manifest(tmp, edit=peers), tmp)
    try:
        la.wait_line("all 3 modules up")
        yield la
    finally:
        la.cleanup()


def test_a_peer_links_launch_is_up_only_once_every_module_is_linked(peer_launch: Launch):
    la = peer_launch
    up = next(line for line in la.lines if "all 3 modules up" in line)
    pids = {m.group(1): int(m.group(2)) for line in la.lines
            if (m := re.match(r"\s+(\w+)\s+starting, pid (\d+)", line))}
    assert set(pids) == {"src_a", "src_b", "sink"}, la.lines
    assert unlinked_pairs(pids) == [], f"said up while modules were apart: {up}"
    assert "not linked directly" not in up


def test_a_restarted_peer_module_is_up_only_once_linked_to_every_module_up(peer_launch: Launch, clients):
    la = peer_launch
    s = clients(la.port)
    before = modules(s)["sink"]
    os.kill(before.pid, signal.SIGKILL)
    seen: dict[str, int] = {}

    def sink_up_again() -> bool:
        now = modules(s)
        if now["sink"].state == "up" and now["sink"].pid != before.pid:
            # the tables read at once: "up" must already mean linked
            seen.update(apart=len(unlinked_pairs({n: m.pid for n, m in now.items()})))
            return True
        return False

    wait_until(sink_up_again, 60, "the sink up again")
    assert seen["apart"] == 0, "the restarted sink said up before linking to the others"
