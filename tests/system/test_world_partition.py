"""Issue 17, partitions, for the shared world model (docs/world.md): three RALs' world nodes on three real routers,
robot c in a network namespace of its own whose router's only link to the mesh is a Unix socket the test relays to
the hub router (tests/system/netns_support.py, as in test_fleet_partition.py). Each node is the RAL's own
``ral.world_bus.WorldNode`` in a process of its own (tests/system/world_agent.py), on a secured fleet's trust: it
applies and merges zones and removals only if the ground station signed them.

- before the cut: station-signed zones ``range`` and ``pond`` added through b reach c through the relay;
- during the cut: the ground station (on the hub) adds a signed no-fly zone ``quarry`` through a and removes
  ``range`` and ``pond``; a's vision reports a target and a's manager completes a survey; c's vision reports a
  target of its own, and a station on c's side moves ``pond`` (the same version as the removal: a conflict). a and
  b agree on their side; c holds none of it (it would fly into ``quarry``, and still refuses ``range``), and a and
  b hold neither c's target nor the moved ``pond``;
- after the heal (nothing replayed: only the 2 s digest exchange can bring the entries across): within
  ``CONVERGE_S`` of the heal every node holds every entry, tombstones included, with the same digest; each entry
  keeps its origin robot, its stamp (written during the cut) and the station's signature (no node's gate refused
  anything); c now refuses a goto into ``quarry``, naming it, and lets one into the removed ``range`` pass; the
  conflict over ``pond`` ends the same everywhere (the greater origin, c, wins: a refuses a goto into the moved
  pond, naming c).

The controls, by hand: with ``WorldNode._on_digest`` returning at once (no anti-entropy), the heal converges
nothing and the test fails at the ``CONVERGE_S`` wait; with ``relay.cut()`` left out, it fails during the cut (c's
edit of ``pond`` is version 3: c already holds the removal).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import msgspec
import pytest

from bbcs.contracts import tasks as t
from bbcs.contracts import world as w
from bbcs.net import free_port
from bbcs.session import local_client, open_session
from bbcs.signing import StationSigner
from bbcs.testing import CutRelay, Processes, wait_port, wait_until
from cromat import certs
from ral.gcs.fleet_cmd import signed_request

sys.path.insert(0, str(Path(__file__).resolve().parent))
from netns_support import (  # noqa: E402
    in_own_netns,
    namespaces_allowed,
    reaches_port_from_own_netns,
    start_ready,
    stop_groups,
)

AGENT = Path(__file__).resolve().parent / "world_agent.py"
LAT0, LON0, ALT = 37.4117, -6.0025, 60.0
M = 1 / 111_320  # degrees of latitude per metre
CONVERGE_S = 20.0
"""From the heal to one model everywhere: c's router reconnects (Zenoh retries a lost link every 1 to 4 s), then
the next digest (every 2 s) differs and the peers' snapshots are asked for (a query of at most 3 s)."""


def poll(predicate: Callable[[], bool], deadline_s: float, what: str) -> float:
    """Ask the agents every 0.1 s (three stdin round trips a poll, not every 10 ms) until ``predicate``; the
    seconds it took. Fails naming ``what`` at the deadline."""
    start = time.monotonic()
    wait_until(lambda: predicate() or time.sleep(0.1) or False, deadline_s, what)
    return time.monotonic() - start


def point(north_m: float, east_m: float) -> tuple[float, float]:
    return LAT0 + north_m * M, LON0 + east_m * M / 0.7944  # cos(37.41°)


def square(north_m: float, east_m: float, half_m: float) -> list[t.Vertex]:
    return [t.Vertex(lat=lat, lon=lon) for lat, lon in (
        point(north_m - half_m, east_m - half_m), point(north_m - half_m, east_m + half_m),
        point(north_m + half_m, east_m + half_m), point(north_m + half_m, east_m - half_m))]


class Agent:
    """A world node's process, asked over its stdin."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.proc = proc

    def ask(self, **cmd: object) -> dict:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        assert line, f"the world agent ended on {cmd}"
        out = json.loads(line)
        assert "error" not in out, out
        return out

    def entry(self, op: str, **cmd: object) -> w.WorldEntry:
        return msgspec.msgpack.decode(bytes.fromhex(self.ask(op=op, **cmd)["entry"]), type=w.WorldEntry)

    def snapshot(self) -> tuple[w.WorldSnapshot, dict[str, int]]:
        out = self.ask(op="snapshot")
        return msgspec.msgpack.decode(bytes.fromhex(out["snapshot"]), type=w.WorldSnapshot), out["refused"]

    def entries(self) -> dict[str, w.WorldEntry]:
        return {e.id: e for e in self.snapshot()[0].entries}

    def refusal(self, lat: float, lon: float) -> str | None:
        return self.ask(op="check", lat=lat, lon=lon, alt=ALT)["refusal"]


def edit(session, robot: str, request: w.WorldPut | w.WorldDelete, signer: StationSigner) -> w.WorldReply:  # noqa: ANN001
    """A ground station's signed edit through ``robot``'s RAL (what ``cromat gcs world --cert`` sends)."""
    payload = msgspec.msgpack.encode(signed_request(request, signer))
    for reply in session.get(w.world_request_key(robot), payload=payload, timeout=10.0):
        if reply.ok is not None:
            return msgspec.msgpack.decode(reply.ok.payload.to_bytes(), type=w.WorldReply)
    raise AssertionError(f"{robot} did not answer the world request")


@pytest.mark.timeout(150)
def test_world_entries_written_on_both_sides_of_a_namespace_cut_reach_every_robot_after_the_heal(
        tmp_path: Path) -> None:
    why = namespaces_allowed()
    if why is not None:
        pytest.skip(why)
    (tmp_path / "ca").mkdir()
    certs.make_ca(tmp_path / "ca")
    certs.make_leaf(tmp_path / "ground", "gcs", ca_dir=tmp_path / "ca")
    signer = StationSigner.from_files(tmp_path / "ground" / "gcs.pem", tmp_path / "ground" / "gcs.key")
    routers = Processes()
    procs: list[subprocess.Popen] = []
    relay = session = None
    try:
        def router(*connect: str) -> int:
            """A router on a free port; not waited for here (each agent waits up to 30 s for its own)."""
            port = free_port()
            routers.start(["-m", "bbcs.router", "--listen", f"tcp/127.0.0.1:{port}",
                           *[arg for link in connect for arg in ("--connect", link)]], stdout=subprocess.DEVNULL)
            return port

        hub = router()
        wait_port(hub, 30)  # the helper's 10 s is short on this machine at a load of 40
        agents: dict[str, Agent] = {}

        def world_agent(name: str, port: int, north_m: float) -> list[str]:
            lat, lon = point(north_m, 0)
            return [sys.executable, str(AGENT), "--robot", name, "--port", str(port), "--here", str(lat), str(lon),
                    str(ALT), "--ca", str(tmp_path / "ca" / "ca.pem"), "--station", "gcs"]

        for name, north in (("a", 0), ("b", 300)):
            port = router(f"tcp/127.0.0.1:{hub}")
            agents[name] = Agent(start_ready(procs, world_agent(name, port, north), name, stdin=subprocess.PIPE))
        sock = tmp_path / "c_link.sock"
        relay = CutRelay.unix(sock, hub)
        c_port = free_port()  # a port inside c's namespace
        agents["c"] = Agent(start_ready(procs, in_own_netns(world_agent("c", c_port, 600), c_port,
                                                            f"unixsock-stream/{sock}"), "c", stdin=subprocess.PIPE))
        a, b, c = agents["a"], agents["b"], agents["c"]
        session = open_session(local_client(hub))
        probe = reaches_port_from_own_netns(hub)
        assert probe.returncode != 0 and "refused" in probe.stderr.lower(), probe.stderr

        # before the cut: zones added through b reach a, and c through the relay (its only link)
        in_range, in_quarry = point(1000, 0), point(-1000, 0)
        for zone_id, where in (("range", square(1000, 0, 100)), ("pond", square(0, 1000, 100))):
            added = edit(session, "b", w.WorldPut(id=zone_id, body=w.NoFlyZone(polygon=where), author="ground"),
                         signer)
            assert added.accepted, added.reason
        poll(lambda: {"range", "pond"} <= set(c.entries()) & set(a.entries()), 30, "the zones at a, and at c through "
             "the relay")
        assert c.refusal(*in_range) is not None and c.refusal(*in_quarry) is None

        relay.cut()
        cut_at = time.time()
        quarry = edit(session, "a", w.WorldPut(id="quarry", body=w.NoFlyZone(polygon=square(-1000, 0, 100),
                                                                             name="quarry"), author="ground"), signer)
        removed = edit(session, "a", w.WorldDelete(id="range", author="ground"), signer)
        pond_gone = edit(session, "a", w.WorldDelete(id="pond", author="ground"), signer)
        assert quarry.accepted and removed.accepted and pond_gone.accepted, (quarry, removed, pond_gone)
        moved = signed_request(w.WorldPut(id="pond", body=w.NoFlyZone(polygon=square(0, 2000, 100)),
                                          author="field"), signer)
        pond = msgspec.msgpack.decode(bytes.fromhex(c.ask(op="edit", request=msgspec.msgpack.encode(moved).hex())[
            "reply"]), type=w.WorldReply)
        assert pond.accepted and pond.entry is not None and pond.entry.version == pond_gone.entry.version == 2
        seen_a = a.entry("see", lat=point(50, 50)[0], lon=point(50, 50)[1], alt=20.0)
        surveyed_a = a.entry("survey", task=7, polygon=[[v.lat, v.lon] for v in square(200, 200, 50)])
        seen_c = c.entry("see", lat=point(650, -40)[0], lon=point(650, -40)[1], alt=21.0)
        written = {e.id: e for e in (quarry.entry, removed.entry, seen_a, surveyed_a, seen_c, pond.entry)
                   if e is not None}
        assert len(written) == 6
        poll(lambda: len({a.snapshot()[0].digest, b.snapshot()[0].digest}) == 1
             and b.entries().get("target.a") == seen_a, 20, "a and b agree during the cut")
        c_cut = c.entries()
        assert not {"quarry", "target.a", "surveyed.a.7"} & set(c_cut) and not c_cut["range"].deleted, c_cut
        assert "target.c" not in a.entries() and "target.c" not in b.entries() and b.entries()["pond"].deleted
        in_pond = point(0, 2000)
        assert a.refusal(*in_pond) is None and c.refusal(*in_pond) is not None
        assert c.refusal(*in_quarry) is None, "c, cut off, knows nothing of the zone"
        assert c.refusal(*in_range) is not None, "c, cut off, still holds the removed zone"

        heal_at = time.time()
        relay.heal()
        snaps: dict[str, tuple[w.WorldSnapshot, dict[str, int]]] = {}

        def one_model() -> bool:
            snaps.update({name: agent.snapshot() for name, agent in agents.items()})
            return len({s.digest for s, _ in snaps.values()}) == 1

        converge_s = poll(one_model, CONVERGE_S, "one world model on a, b and c after the heal")
        print(f"world model converged {converge_s:.2f} s after the heal")

        models = {name: {e.id: e for e in s.entries} for name, (s, _) in snaps.items()}
        assert models["a"] == models["b"] == models["c"]
        assert sorted(models["c"]) == ["pond", "quarry", "range", "surveyed.a.7", "target.a", "target.c"]
        origins = {"quarry": "a", "range": "a", "target.a": "a", "surveyed.a.7": "a", "target.c": "c", "pond": "c"}
        for entry_id, entry in written.items():  # origin, stamp, signature: as written, not as merged
            assert models["c"][entry_id] == entry and models["a"][entry_id] == entry, entry_id
            assert entry.origin == origins[entry_id] and cut_at <= entry.stamp <= heal_at, entry
        assert models["b"]["target.c"].body == w.Target(lat=point(650, -40)[0], lon=point(650, -40)[1], alt=21.0,
                                                        seen_by="c", seen_at=seen_c.stamp)
        assert models["c"]["quarry"].signature and models["c"]["range"].deleted and models["c"]["range"].version == 2
        assert all(refused == {} for _, refused in snaps.values()), snaps

        why_not = c.refusal(*in_quarry)
        assert why_not is not None and "inside no-fly zone 'quarry'" in why_not and "set by ground via a" in why_not
        assert c.refusal(*in_range) is None, "the removal made during the cut reached c"
        why_not = a.refusal(*in_pond)
        assert why_not is not None and "inside no-fly zone 'pond', set by field via c" in why_not, why_not
        assert relay.accepted >= 2, "the heal went through a new relayed connection"
    finally:
        if session is not None:
            session.close()
        stop_groups(procs)
        if relay is not None:
            relay.close()
        routers.stop_all()
