"""Partition tests' shared machinery: a robot in a network namespace of its own, cut off the mesh and healed.

``in_own_netns`` runs a command (a robot's process) in a new network namespace (``unshare -n``: only its own
loopback, so it reaches no port of the others) together with the robot's router, whose only link to the mesh is a
Unix socket. The test relays that socket to the hub router's TCP port with :class:`bbcs.testing.CutRelay`, and cuts
and heals the relay. Used by test_fleet_partition.py and test_world_partition.py.
"""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from bbcs.testing import child_env

ROOT = Path(__file__).resolve().parents[2]


def namespaces_allowed() -> str | None:
    """None if this machine lets the test make network namespaces, else why not (the skip reason)."""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return "unshare or ip not installed"
    probe = subprocess.run(["unshare", "-n", "ip", "link", "set", "lo", "up"], capture_output=True, text=True)
    return None if probe.returncode == 0 else f"network namespaces not allowed here: {probe.stderr.strip()}"


def in_own_netns(cmd: Sequence[str], router_port: int, link: str) -> list[str]:
    """argv running ``cmd`` in a new network namespace, with a router listening on 127.0.0.1:``router_port``
    inside it (a port number that means nothing outside) and linked to the mesh only through ``link``."""
    router = [sys.executable, "-m", "bbcs.router", "--listen", f"tcp/127.0.0.1:{router_port}", "--connect", link]
    shell = f"ip link set lo up || exit 97; {shlex.join(router)} >/dev/null & exec {shlex.join(cmd)}"
    return ["unshare", "-n", "sh", "-c", shell]


def start_ready(procs: list[subprocess.Popen], argv: Sequence[str], what: str, *,
                stdin: int | None = None) -> subprocess.Popen:
    """Start ``argv`` in a process group of its own (stopped by :func:`stop_groups`) and wait for its ``ready``
    line on stdout."""
    proc = subprocess.Popen(list(argv), cwd=str(ROOT), env=child_env(), stdin=stdin, stdout=subprocess.PIPE,
                            text=True, start_new_session=True)
    procs.append(proc)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "ready", f"{what} did not start"
    return proc


def reaches_port_from_own_netns(port: int) -> subprocess.CompletedProcess:
    """Try to connect to 127.0.0.1:``port`` from a fresh network namespace (the proof that one is cut off)."""
    probe = [sys.executable, "-c", f"import socket; socket.create_connection(('127.0.0.1', {port}), 1)"]
    return subprocess.run(["unshare", "-n", "sh", "-c", f"ip link set lo up && exec {shlex.join(probe)}"],
                          capture_output=True, text=True)


def stop_groups(procs: list[subprocess.Popen]) -> None:
    """SIGTERM each process group (a namespaced robot's router goes with it), SIGKILL any that lingers."""
    for p in procs:
        try:
            os.killpg(p.pid, signal.SIGTERM)  # also when p ended: its router may still run in its group
        except ProcessLookupError:
            pass
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(5)
        for stream in (p.stdin, p.stdout):
            if stream is not None:
                stream.close()
