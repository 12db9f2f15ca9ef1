"""Which pairs of a robot's peer modules (``[bus] links = "peers"``) have linked directly, read from the kernel.

Zenoh forms the peer links after each module is up (the router gossips the locators; each pair connects once), and
a datum sent between two modules while their link forms can be lost (docs/bus.md). The manager runs on the same
host as its modules, so it can see the links where they are: each module's TCP sockets (``/proc/PID/fd``) in the
kernel's table (``/proc/PID/net/tcp``). Two modules are linked when one has a connection to a port the other listens
on. Nothing here touches the bus.
"""

from __future__ import annotations

import itertools
import os
from pathlib import Path

LISTEN, ESTABLISHED = "0A", "01"
"""TCP states as ``/proc/net/tcp`` writes them."""


def tcp_ports(pid: int) -> tuple[set[int], set[int]]:
    """The ports process ``pid`` listens on, and the remote ports of its established TCP connections (IPv4, the
    peers' 127.0.0.1). Empty sets for a process that is gone."""
    inodes = set()
    try:
        fds = list(Path(f"/proc/{pid}/fd").iterdir())
        table = Path(f"/proc/{pid}/net/tcp").read_text().splitlines()[1:]
    except OSError:
        return set(), set()
    for fd in fds:
        try:
            target = os.readlink(fd)
        except OSError:  # closed since the listing
            continue
        if target.startswith("socket:["):
            inodes.add(target[len("socket:["):-1])
    listening, remote = set(), set()
    for line in table:
        fields = line.split()
        if len(fields) > 9 and fields[9] in inodes:
            if fields[3] == LISTEN:
                listening.add(int(fields[1].rsplit(":", 1)[1], 16))
            elif fields[3] == ESTABLISHED:
                remote.add(int(fields[2].rsplit(":", 1)[1], 16))
    return listening, remote


def unlinked_pairs(pids: dict[str, int]) -> list[tuple[str, str]]:
    """The pairs of named processes with no TCP connection from one to a port the other listens on, sorted."""
    ports = {name: tcp_ports(pid) for name, pid in pids.items()}
    return [(a, b) for a, b in itertools.combinations(sorted(ports), 2)
            if not (ports[a][1] & ports[b][0] or ports[b][1] & ports[a][0])]


def verdict(unlinked: list[tuple[str, str]], waited_s: float, wait_s: float) -> list[tuple[str, str]] | None:
    """What the manager does with the pairs still apart after waiting ``waited_s`` of at most ``wait_s``: None, keep
    waiting; else count the module up, naming those pairs (empty: every pair linked)."""
    return None if unlinked and waited_s < wait_s else unlinked
