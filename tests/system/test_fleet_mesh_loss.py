"""Issue 17, losing the mesh: two robots meshed only through a hub router (the "mesh"), each flying its fleet
share; the hub is killed mid-mission.

Robot b's ground station is on b's own router, so b keeps its ground link: it keeps flying its share to the end
(its DSP simulator keeps receiving: the re-sent path that adds a's unvisited targets, since a is gone from b's
view) and no failsafe fires. Robot a's only ground station was across the mesh: a's own link-loss failsafe fires
(hold: ABORT reaches a's DSP) and a flies no more fleet work. Each robot runs on its own rules, without its peers.
"""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

import pytest

from bbcs.session import open_session
from bbcs.testing import Processes, start_router, wait_until
from ral.fleet_gcs import FleetView
from ral.gcs.api import Gcs, session_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_fleet_alloc import FLEET_SPEED, FLY_ALT, HOMES, N_MODULES, FleetRobot, cli_post, grid, take_off_all  # noqa: E402

FAILSAFE_S = 2.0


@pytest.mark.timeout(420)
def test_a_robot_that_loses_the_mesh_keeps_flying_its_task_under_its_own_failsafe_rules(tmp_path: Path) -> None:
    procs = Processes()
    robots: dict[str, FleetRobot] = {}
    stations: list[Gcs] = []
    view = session = None
    try:
        hub = start_router(procs)
        ral = {"failsafe_timeout_s": str(FAILSAFE_S), "heartbeat_timeout_s": "3"}
        for name in ("uav_a", "uav_b"):
            robots[name] = FleetRobot(tmp_path, name, [hub], ral=ral)
        for r in robots.values():
            r.launch.wait_line(f"all {N_MODULES} modules up", 120)
        a, b = robots["uav_a"], robots["uav_b"]
        gcs_a = Gcs(session_config([f"tcp/127.0.0.1:{hub}"]), name="ground_a", link=["uav_a"], timeout_s=10.0)
        stations.append(gcs_a)
        gcs_b = Gcs(session_config([f"tcp/127.0.0.1:{b.launch.port}"]), name="ground_b", link=["uav_b"],
                    timeout_s=10.0)
        stations.append(gcs_b)
        wait_until(lambda: gcs_a.robots(1.0) == ["uav_a", "uav_b"], 30, "both robots through the hub")
        take_off_all(gcs_a, ["uav_a"])
        take_off_all(gcs_b, ["uav_b"])
        session = open_session(session_config([f"tcp/127.0.0.1:{b.launch.port}"]))
        view = FleetView(session)

        # b: four targets ~90 m apart around its home (a long share); a: two ~190 m from its home
        b_pts = [grid(*HOMES["uav_b"], n, e) for n, e in ((4, 0), (8, 4), (4, 8), (0, 4))]
        a_pts = [grid(*HOMES["uav_a"], n, e) for n, e in ((12, -12), (-12, -12))]
        spec = ([f"b{i},{lat},{lon},{FLY_ALT}" for i, (lat, lon) in enumerate(b_pts)]
                + [f"a{i},{lat},{lon},{FLY_ALT}" for i, (lat, lon) in enumerate(a_pts)])
        done = cli_post(hub, "patrol", spec, speed=FLEET_SPEED)
        assert done.returncode == 0, done.stdout + done.stderr
        # the CLI's answer and the view's state events have no order between them: wait for the view
        dec = view.wait(lambda: view.agreed("patrol", {"uav_a", "uav_b"}), 10)
        assert dec is not None and sorted(dec.routes["uav_b"]) == ["b0", "b1", "b2", "b3"], dec
        assert sorted(dec.routes["uav_a"]) == ["a0", "a1"], dec
        route_b = dec.routes["uav_b"]
        wait_until(lambda: route_b[0] in view.visited("patrol"), 60, "b visited its first target")
        assert route_b[-1] not in view.visited("patrol")

        cut = time.time()
        left_a = {a_pts[i] for i in (0, 1) if f"a{i}" not in view.visited("patrol")}
        assert left_a, "a visited both its targets before the cut"
        n_a, n_b = a.count(), b.count()
        for proc in procs.procs:  # the hub is the only process the test started itself
            proc.send_signal(signal.SIGKILL)
        # a: its ground station was across the mesh; its own failsafe fires and holds (ABORT to its DSP)
        wait_until(lambda: "ABORT" in [c["name"] for c in a.commands()[n_a:]], FAILSAFE_S + 20,
                   "a's failsafe hold reached its DSP")
        # b: keeps its ground link and flies its share to the end, a's unvisited targets added
        wait_until(lambda: set(route_b) <= view.visited("patrol"), 120, "b flew its whole share after the cut")
        assert "ABORT" not in [c["name"] for c in b.commands()[n_b:]], "b must not fail safe: its link is up"
        state = gcs_b.state("uav_b")
        assert state.link == "up" and state.airborne, state
        after = view.decisions("patrol")["uav_b"]
        assert after.round >= 1 and after.bidders == ["uav_b"], after
        own = [x for x in after.routes["uav_b"] if x.startswith("b")]
        assert own == [x for x in route_b if x in own] and after.routes["uav_b"][:len(own)] == own, (
            "b's own remaining targets first, in their order")
        assert left_a <= set(b.waypoints(n_b)), "b's DSP did not receive a's unvisited targets after the cut"
        wait_until(lambda: {"a0", "a1"} <= view.visited("patrol"), 120, "b flew a's targets too")
        names_a = [c["name"] for c in a.commands()[n_a:]]
        held = names_a.index("ABORT")  # before it, a (cut off too) may take over b's targets: mission unchanged
        assert "ADD_WAYPOINT" not in names_a[held:], f"a flew fleet work after its failsafe: {names_a[held:]}"
        print(f"mesh cut: a failed safe, b flew on; cut at {cut:.1f}")
    finally:
        if view is not None:
            view.close()
        if session is not None:
            session.close()
        for g in stations:
            g.close()
        for r in reversed(list(robots.values())):
            r.launch.stop()
            r.launch.cleanup()
        procs.stop_all()

