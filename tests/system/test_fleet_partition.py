"""Issue 17, partitions: robot c in a network namespace of its own, made by the test (``unshare -n``: only its own
loopback, so c's RAL and router cannot reach any port of the others); its router's only link to the mesh is a
Unix socket, relayed by the test to the hub router's TCP port. Cutting that relay partitions c from the mesh;
reopening it heals.

The robots are the bench's fleet agents (``bench/fleet.py --agent``): the RAL's own FleetLink and protocol on real
Zenoh routers, flying point robots (no DSP stack). What is checked:

- cut: each side decides without the other (a and b agree on a new round without c; c alone takes everything),
  so no target is left without a robot on either side;
- heal: c's router reconnects by itself, and all three agree again on one allocation over everyone's bids, each
  target held by one robot;
- the safe state slot crossing the mesh (each RAL's fleet state, the one the protocol depends on) comes back:
  after the heal the ground router's view holds c's current state again (a state slot's guarantee is the latest
  value, not every intermediate one).

Safe *streams* published during a cut are not replayed after the heal, except GRI events
(tests/ral/gcs/test_events_replay.py); this test does not claim otherwise (docs/fleet.md).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bbcs.contracts.fleet import FleetTarget, FleetTask
from bbcs.net import free_port
from bbcs.session import local_client, open_session
from bbcs.testing import CutRelay, Processes, start_router, wait_until
from ral.fleet_gcs import FleetView

sys.path.insert(0, str(Path(__file__).resolve().parent))
from netns_support import (  # noqa: E402
    in_own_netns,
    namespaces_allowed,
    reaches_port_from_own_netns,
    start_ready,
    stop_groups,
)

ROOT = Path(__file__).resolve().parents[2]
BENCH = ROOT / "bench" / "fleet.py"
LAT0, LON0, ALT = 37.4117, -6.0025, 22.0


def agent(procs: list[subprocess.Popen], name: str, port: int, north: float, east: float,
          netns_link: str | None = None) -> subprocess.Popen:
    """An agent on its router. With ``netns_link``: router and agent in a new network namespace, the router
    linked to the mesh only through that endpoint."""
    cmd = [sys.executable, str(BENCH), "--agent", name, "--port", str(port), "--north", str(north),
           "--east", str(east), "--speed", "1"]
    return start_ready(procs, cmd if netns_link is None else in_own_netns(cmd, port, netns_link), f"agent {name}")


@pytest.mark.timeout(240)
def test_a_robot_cut_off_in_its_own_network_namespace_heals_into_one_allocation(tmp_path: Path) -> None:
    why = namespaces_allowed()
    if why is not None:
        pytest.skip(why)
    routers = Processes()
    procs: list[subprocess.Popen] = []
    relay = view = session = None
    try:
        hub = start_router(routers)
        ports = {}
        for name in ("a", "b"):
            ports[name] = free_port()
            routers.start(["-m", "bbcs.router", "--listen", f"tcp/127.0.0.1:{ports[name]}", "--connect",
                           f"tcp/127.0.0.1:{hub}"], stdout=subprocess.DEVNULL)
        sock = tmp_path / "c_link.sock"
        relay = CutRelay.unix(sock, hub)
        agent(procs, "a", ports["a"], -300, -300)
        agent(procs, "b", ports["b"], 0, 2000)
        c_port = free_port()  # a port inside c's namespace: the same number means nothing outside it
        agent(procs, "c", c_port, 2000, 1000, netns_link=f"unixsock-stream/{sock}")
        session = open_session(local_client(hub))
        view = FleetView(session)
        everyone = {"a", "b", "c"}

        def alive() -> set[str]:
            from bbcs import keys

            return {str(r.ok.key_expr).split("/")[1] for r in session.liveliness().get(
                keys.alive_pattern("*", "ral"), timeout=2.0) if r.ok is not None}

        wait_until(lambda: alive() == everyone, 30, "c's token seen through the relay from its namespace")
        # c's namespace has no route to the hub's TCP port: the relay is its only way out
        probe = reaches_port_from_own_netns(hub)
        assert probe.returncode != 0 and "refused" in probe.stderr.lower(), probe.stderr

        m = 1 / 111_320
        targets = [FleetTarget(id=f"t{i}", lat=LAT0 + (i % 3) * 900 * m, lon=LON0 + (i // 3) * 900 * m, alt=ALT)
                   for i in range(9)]
        view.post(FleetTask(id="area", targets=targets))
        first = view.wait(lambda: view.agreed("area", everyone), 20)
        assert first is not None and first.bidders == ["a", "b", "c"], view.decisions("area")
        assert first.routes["c"], first.routes

        relay.cut()
        wait_until(lambda: alive() == {"a", "b"}, 30, "c gone from the mesh's view")
        ab = view.wait(lambda: (d := view.agreed("area", {"a", "b"})) is not None and d.round > first.round and d, 20)
        assert ab and ab.bidders == ["a", "b"], view.decisions("area")
        assert sorted(t for r in ab.routes.values() for t in r) == sorted(t.id for t in targets)
        with view.lock:
            c_before = view.states["c"].stamp

        relay.heal()
        wait_until(lambda: alive() == everyone, 60, "c's router reconnected by itself")
        healed = view.wait(lambda: (d := view.agreed("area", everyone)) is not None and d.round > ab.round and d, 30)
        assert healed, view.decisions("area")
        assert healed.bidders == ["a", "b", "c"]
        owners = [t for r in healed.routes.values() for t in r]
        assert sorted(owners) == sorted(t.id for t in targets), healed.routes
        c_side = view.decisions("area")["c"]
        assert c_side.round == healed.round and c_side.digest == healed.digest
        with view.lock:
            assert view.states["c"].stamp > c_before, "c's fleet state after the heal reached the ground router"
        assert relay.accepted >= 2, "the heal went through a new relayed connection"
    finally:
        if view is not None:
            view.close()
        if session is not None:
            session.close()
        stop_groups(procs)
        if relay is not None:
            relay.close()
        routers.stop_all()
