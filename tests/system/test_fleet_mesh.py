"""Issue 17, the mesh: robots launched from uav1_sim.toml under their own names, each with its own router, the
routers meshed by Zenoh itself through ``[bus] peers`` (loopback, no scouting).

A ground station on any router sees every robot and its GRI state; a second robot under a name already alive on
the mesh is refused before it starts anything; a robot whose peer router dies keeps flying its path, shown by
what its simulated DSP received and by the task's completion.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from pathlib import Path

from bbcs.contracts import gri
from bbcs.testing import wait_until
from ral.gcs.api import Gcs, session_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "module_manager"))
from launch_support import Launch, group_members  # noqa: E402
from test_gcs_mission import N_MODULES, grid_path, sim_manifest  # noqa: E402


def fleet_manifest(tmp_path: Path, name: str, peers: list[int]) -> tuple[Path, Path]:
    """uav1_sim.toml renamed to ``name``, meshed with the routers on ``peers`` (ports on 127.0.0.1)."""
    folder = tmp_path / name
    folder.mkdir(exist_ok=True)

    def edit(text: str) -> str:
        text = text.replace('name = "uav1"', f'name = "{name}"', 1)
        endpoints = ", ".join(f'"tcp/127.0.0.1:{p}"' for p in peers)
        return text.replace("[bus]\n", f"[bus]\npeers = [{endpoints}]\n", 1)

    return sim_manifest(folder, edit=edit)


def launch(tmp_path: Path, name: str, peers: list[int]) -> tuple[Launch, Path]:
    manifest, record = fleet_manifest(tmp_path, name, peers)
    return Launch(manifest, tmp_path / name), record


def router_pid(pgid: int) -> int:
    """The robot router (``python -m bbcs.router``) among a launch's processes."""
    for pid in group_members(pgid):
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"bbcs.router" in cmd:
            return pid
    raise AssertionError(f"no router process in process group {pgid}")


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
        assert stations[0].robots(1.0) == names
    finally:
        for gcs in stations:
            gcs.close()
        for la in reversed(launches):
            la.stop()
            la.cleanup()


def test_robot_that_loses_the_mesh_keeps_flying_its_path(tmp_path: Path) -> None:
    launches: list[Launch] = []
    gcs = None
    try:
        a, _ = launch(tmp_path, "uav_a", [])
        launches.append(a)
        a.wait_line(f"all {N_MODULES} modules up", 90)
        b, record = launch(tmp_path, "uav_b", [a.port])
        launches.append(b)
        b.wait_line(f"all {N_MODULES} modules up", 90)
        # the ground station sits on b's own router (a robot's link to its station is not the mesh)
        gcs = gcs_on(b.port, "ground_b", ["uav_b"])
        wait_until(lambda: gcs.robots(1.0) == ["uav_a", "uav_b"], 30, "both robots seen through the mesh")
        states: list[gri.GriState] = []
        events: list[gri.GriEvent] = []
        gcs.watch("uav_b", states.append)
        gcs.events("uav_b", events.append)
        wait_until(lambda: bool(states) and states[-1].position is not None and states[-1].airborne is not None,
                   30, "uav_b's telemetry")
        reply = gcs.send("uav_b", gri.TakeOff(height=10.0))
        assert reply.accepted, reply.reason
        wait_until(lambda: any(e.kind == "task_completed" and e.task_id == reply.task_id for e in events),
                   40, "take-off completed")
        wait_until(lambda: bool(states[-1].airborne) and states[-1].position is not None, 15, "airborne")
        path = grid_path(states[-1].position, scale=3)
        reply = gcs.send("uav_b", gri.FollowPath(waypoints=path, speed=5.0))
        assert reply.accepted, reply.reason
        wait_until(lambda: bool(states[-1].waypoints_queued), 20, "uav_b's DSP queue filled")

        os.kill(router_pid(a.pgid), signal.SIGKILL)  # the mesh is gone: b's peer router dies mid-path
        wait_until(lambda: gcs.robots(1.0) == ["uav_b"], 30, "uav_a gone from the robot list")
        killed_at = len(read_record(record))
        ends = [e for e in events if e.task_id == reply.task_id and e.kind != "task_accepted"]
        assert not ends, f"the path ended before the peer router died: {ends}"

        wait_until(lambda: any(e.task_id == reply.task_id and e.kind != "task_accepted" for e in events),
                   120, "the path task ended")
        done = next(e for e in events if e.task_id == reply.task_id and e.kind != "task_accepted")
        assert done.kind == "task_completed", done
        commands = read_record(record)
        added = [(round(c["fields"]["lat"], 4), round(c["fields"]["lon"], 4))
                 for c in commands if c["name"] == "ADD_WAYPOINT"]
        assert added[-len(path):] == [(w.lat, w.lon) for w in path]
        stopping = [c for c in commands[killed_at:] if c["name"] in ("ABORT", "INVALIDATE_PATH")
                    or (c["name"] == "SET_MODE" and c["fields"]["mode"] == 5)]
        assert not stopping, f"the robot stopped its path when the mesh went: {stopping}"
        end = states[-1]
        assert end.position is not None and abs(end.position.lat - path[-1].lat) * 111_320 < 5.0
    finally:
        if gcs is not None:
            gcs.close()
        for la in reversed(launches):
            la.stop()
            la.cleanup()


def read_record(record: Path) -> list[dict]:
    import json

    if not record.exists():
        return []
    text = record.read_text()
    return [json.loads(line) for line in text[: text.rfind("\n") + 1].splitlines() if line.strip()]
