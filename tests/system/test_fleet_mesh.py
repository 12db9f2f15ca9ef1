"""Issue 17, the mesh: robots launched from uav1_sim.toml under their own names, each with its own router, the
routers meshed by Zenoh itself through ``[bus] peers`` (loopback, no scouting).

A ground station on any router sees every robot and its GRI state; a second robot under a name already alive on
the mesh is refused before it starts anything; one that joins later, when its launch could not check its name,
is refused by the mesh itself (its router's Zenoh id comes from the robot name), says so on its launch's output,
and nothing of it crosses.
"""

from __future__ import annotations

import re
import sys
import threading
from pathlib import Path

from bbcs.contracts import gri
from bbcs.net import free_port
from bbcs.testing import wait_until
from module_manager.fleet import drop_sections
from ral.gcs.api import Gcs, NoReply, session_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "module_manager"))
from launch_support import ROOT, Launch, group_members  # noqa: E402
from test_gcs_mission import sim_manifest  # noqa: E402

from modules.dsp.sim.record import read_record

N_MODULES = 5
"""uav1_sim.toml's modules without vision."""


VISION_SECTIONS = {"modules.vision", "tasks.track", "tasks.follow_vision_path"}
"""The vision module and the tasks that need it (``drop_sections``, as a fleet manifest's ``drop``): left out where
a test does not use them (its simulated camera takes ~40 % of a core per robot, and several robots share this
machine's 2 cores)."""


def fleet_manifest(tmp_path: Path, name: str, peers: list[int]) -> tuple[Path, Path]:
    """uav1_sim.toml renamed to ``name``, meshed with the routers on ``peers`` (ports on 127.0.0.1)."""
    folder = tmp_path / name
    folder.mkdir(exist_ok=True)

    conf = folder / f"{name}.conf"  # the robot .conf names the robot too (ROBOT: uav1)
    text = (ROOT / "bbcs_conf" / "uav1.conf").read_text()
    assert "\nROBOT: uav1\n" in text, "uav1.conf no longer names its robot on a ROBOT line"
    conf.write_text(text.replace("\nROBOT: uav1\n", f"\nROBOT: {name}\n", 1))

    def edit(text: str) -> str:
        text = text.replace('name = "uav1"', f'name = "{name}"', 1)
        text = re.sub(r'(\[robot\][^\[]*?conf = )"[^"]*"', rf'\g<1>"{conf}"', text, count=1)
        endpoints = ", ".join(f'"tcp/127.0.0.1:{p}"' for p in peers)
        return text.replace("[bus]\n", f"[bus]\npeers = [{endpoints}]\n", 1)

    return sim_manifest(folder, edit=edit)


def launch(tmp_path: Path, name: str, peers: list[int], port: int | None = None) -> tuple[Launch, Path]:
    """A robot of this test: no vision (nothing here needs it); ``port``: where its router listens."""
    manifest, record = fleet_manifest(tmp_path, name, peers)
    manifest.write_text(drop_sections(manifest.read_text(), VISION_SECTIONS))
    return Launch(manifest, tmp_path / name, port=port), record


def gcs_on(port: int, name: str, link: list[str]) -> Gcs:
    return Gcs(session_config([f"tcp/127.0.0.1:{port}"]), name=name, link=link, timeout_s=10.0)


def test_meshed_robots_are_seen_from_any_router_and_duplicates_are_refused(tmp_path: Path) -> None:
    launches: list[Launch] = []
    stations: list[Gcs] = []
    try:
        a, _ = launch(tmp_path, "uav_a", [])
        launches.append(a)
        a.wait_line(f"all {N_MODULES} modules up", 90)
        b, _ = launch(tmp_path, "uav_b", [a.port])
        launches.append(b)
        b.wait_line(f"all {N_MODULES} modules up", 90)
        assert "robot name 'uav_b' is free on the mesh" in b.wait_line("  mesh ")
        c, _ = launch(tmp_path, "uav_c", [b.port])  # a chain: a <- b <- c, routed by Zenoh through b
        launches.append(c)
        c.wait_line(f"all {N_MODULES} modules up", 90)

        names = ["uav_a", "uav_b", "uav_c"]
        for la in (a, c):  # both ends of the chain see every robot and its GRI state
            gcs = gcs_on(la.port, f"ground_{la.port}", [])
            stations.append(gcs)
            wait_until(lambda g=gcs: g.robots(1.0) == names, 30, "every robot in the robot list")
            seen: dict[str, gri.GriState] = {}
            lock = threading.Lock()

            def on_state(state: gri.GriState, seen=seen, lock=lock) -> None:
                with lock:
                    seen[state.robot] = state

            gcs.watch("*", on_state)
            wait_until(lambda seen=seen: sorted(seen) == names and all(s.manager_up for s in seen.values()),
                       30, "a GRI state with the manager up from every robot")
            assert {s.kind for s in seen.values()} == {"uav"}

        # a duplicate name, meshed through c (two hops from a): refused before anything starts
        dup, _ = launch(tmp_path, "uav_a", [c.port])
        launches.append(dup)
        code = dup.proc.wait(60)
        out = "\n".join(dup.lines)
        assert code != 0, out
        assert "robot name 'uav_a' is already alive on the fleet mesh" in out, out
        assert "router      listening" not in out and "modules up" not in out, out
        wait_until(lambda: group_members(dup.pgid) == [], 20, "nothing of the refused launch left")
        # the three robots are still there (a 1 s query can come back empty on a loaded machine: ask again)
        wait_until(lambda: stations[0].robots(2.0) == names, 30, "the three robots after the refused duplicate")
    finally:
        for gcs in stations:
            gcs.close()
        for la in reversed(launches):
            la.stop()
            la.cleanup()


def test_a_robot_of_the_same_name_joining_later_is_refused_by_the_mesh_itself(tmp_path: Path) -> None:
    port_a = free_port()
    (tmp_path / "first").mkdir()
    (tmp_path / "second").mkdir()
    launches: list[Launch] = []
    gcs = None
    try:
        # b first: its peer (a's router) is not up yet, so its launch cannot check the name and starts alone
        b, record_b = launch(tmp_path / "second", "uav_d", [port_a])
        launches.append(b)
        b.wait_line(f"all {N_MODULES} modules up", 90)
        assert "not checked" in b.wait_line("  mesh "), b.lines
        # a robot of the same name comes up where b's router keeps dialling
        a, record_a = launch(tmp_path / "first", "uav_d", [], port=port_a)
        launches.append(a)
        a.wait_line(f"all {N_MODULES} modules up", 90)
        refused = b.wait_line("mesh refused", 30)
        assert f"the router at tcp/127.0.0.1:{port_a} closed this router's link" in refused, b.lines
        assert "robot names must be unique" in refused
        assert "another robot of this name tried to join the mesh here" in a.wait_line("mesh refused", 30), a.lines

        # nothing of b crosses: a take-off through a's router reaches a's DSP simulator, not b's
        gcs = gcs_on(port_a, "ground", ["uav_d"])
        wait_until(lambda: gcs.robots(1.0) == ["uav_d"], 30, "uav_d seen from a's router")
        def placed() -> bool:
            try:
                tel = gcs.state("uav_d", 2.0).telemetry
            except NoReply:
                return False
            return tel is not None and tel.position is not None

        wait_until(placed, 30, "a's telemetry in its GRI state")

        def told() -> list[str]:  # what a station on a's router is told, in the robot's GRI state
            try:
                errors = gcs.state("uav_d", 2.0).errors
            except NoReply:
                return []
            return [e.detail for e in errors if e.module == "router" and e.name == "DUPLICATE_ROBOT_NAME"]

        wait_until(told, 30, "the refused duplicate in a's GRI state errors")
        assert "another robot of this name tried to join the mesh here" in told()[0]
        before_a, before_b = len(read_record(record_a)), len(read_record(record_b))
        reply = gcs.send("uav_d", gri.TakeOff(height=10.0))
        assert reply.accepted, reply.reason
        wait_until(lambda: any(r["name"] == "SET_MODE" for r in read_record(record_a)[before_a:]), 30,
                   "the take-off at a's DSP simulator")
        assert read_record(record_b)[before_b:] == [], read_record(record_b)[before_b:]
        assert b.proc.poll() is None  # b is refused by the mesh, not stopped: it keeps flying on its own rules
    finally:
        if gcs is not None:
            gcs.close()
        for la in reversed(launches):
            la.stop()
            la.cleanup()
