"""A lockstep flight on the shipped uav1_sim.toml, for the lockstep system test and bench/sim.py.

``fly_mission`` launches the robot with ``[sim] lockstep = true`` (added unless the shipped manifest has it) at
``--speed max``, flies take-off, a goto and a landing through the GCS API, keeps watching ``watch_s`` simulated
seconds after the landing, and returns what the simulated DSP received and how long it all took, simulated and
on the wall. Simulated time is read from the GRI state's stamps (the RAL's clock: the simulation's time).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bbcs.contracts import gri
from bbcs.contracts import tasks as t
from bbcs.geojson import read_polygon

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "module_manager"))
from launch_support import Launch, cmdline, group_members  # noqa: E402
from test_gcs_mission import GRID_DEG, ROBOT, SimRobot, connect, sim_manifest  # noqa: E402

from modules.dsp.sim.record import read_record  # noqa: E402

N_MODULES = 6
GOTO_SPEED = 5.0
ROOT = Path(__file__).resolve().parents[2]
SURVEY_AREA = ROOT / "bbcs_conf" / "uav1_survey_area.geojson"
"""The shipped survey area: 71 m x 89 m north of the DSP simulator's home."""


@dataclass
class Flight:
    record: list[dict[str, Any]]
    """Every command the simulated DSP applied, in order."""
    sim_s: float
    """Simulated seconds from the first task to the end of the watch."""
    wall_s: float
    """Wall seconds for the same."""
    events: list[str]
    cpu_s: dict[str, float] | None = None
    """Processor seconds each process of the launch had used by the end (where the time goes)."""
    home: tuple[float, float, float] | None = None
    """The take-off point the GRI reported (lat, lon, alt)."""

    def commands(self) -> list[tuple[str, Any]]:
        """The mission's part of the record as command sequence and fields (its times left out: they are not the
        contract): what the DSP applied once simulated time moved. Before that (time 0) come the DSP module's
        start-up sequence and whatever modules send while the robot starts, which no step orders."""
        return [(r["name"], r["fields"]) for r in self.record if r["t"] > 0]

    def startup(self) -> list[tuple[str, Any]]:
        """The record at simulated time 0: the start-up sequence (and the modules' first commands)."""
        return [(r["name"], r["fields"]) for r in self.record if r["t"] == 0]


PROGRAMS = ("modules.", "module_manager.cli", "bbcs.router", "ral")


def cpu_by_process(pgid: int) -> dict[str, float]:
    """Processor seconds (user + system) of every live process in the launch's process group, by what it runs."""
    tick = os.sysconf("SC_CLK_TCK")
    out: dict[str, float] = {}
    for pid in group_members(pgid):
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        argv = cmdline(pid)
        name = next((a for a in reversed(argv) if a.startswith(PROGRAMS)), " ".join(argv[-2:]))
        out[name] = out.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / tick
    return out


def lockstep_manifest(tmp_path: Path) -> tuple[Path, Path]:
    def edit(text: str) -> str:
        if "lockstep = true" in text:
            return text
        return text.replace("\n[bus]\n", "\n[sim]\nlockstep = true\n\n[bus]\n", 1)

    return sim_manifest(tmp_path, edit=edit, time_scale=1.0)


def busy_processes(n: int) -> list[subprocess.Popen]:
    """``n`` processes spinning on a processor each (a loaded machine)."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        p.kill()
    for p in procs:
        p.wait(10)


def goal_of(home: tuple[float, float, float] | None) -> tuple[float, float, float]:
    """The goto's goal: two 10^-4-degree grid cells (22 m) north of the take-off point's cell, 10 m above it (on
    the grid, so what the DSP receives equals what the ground station sent)."""
    assert home is not None
    lat, lon, alt = home
    return (round(round(lat / GRID_DEG) * GRID_DEG + 2 * GRID_DEG, 4), round(round(lon / GRID_DEG) * GRID_DEG, 4),
            alt + 10.0)


def _done(robot: SimRobot, task_id: int, timeout_s: float, what: str) -> str:
    event = robot.wait_event(lambda e: e.task_id == task_id and e.kind in ("task_completed", "task_failed"),
                             timeout_s, what)
    return event.kind if event.kind == "task_completed" else f"{event.kind}: {event.detail}"


def fly_mission(tmp_path: Path, *, watch_s: float = 20.0, timeout_s: float = 240.0) -> Flight:
    tmp_path.mkdir(parents=True, exist_ok=True)
    manifest, record = lockstep_manifest(tmp_path)
    la = Launch(manifest, tmp_path, "--speed", "max")
    gcs = None
    try:
        la.wait_line(f"all {N_MODULES} modules up", 120)
        gcs = connect(la.port, "ground1")
        robot = SimRobot(la, gcs, record)
        first = robot.wait_state(lambda s: s.link == "up" and s.position is not None and s.home is not None,
                                 timeout_s, "a GRI state with position, home and this GCS linked")
        home = first.home
        assert home is not None
        wall0, sim0 = time.monotonic(), first.stamp
        kinds = []
        reply = gcs.send(ROBOT, gri.TakeOff(height=10.0))
        assert reply.accepted, reply.reason
        kinds.append(_done(robot, reply.task_id, timeout_s, "take-off ended"))
        lat, lon, alt = goal_of((home.lat, home.lon, home.alt))
        reply = gcs.send(ROBOT, gri.Goto(waypoints=[gri.Waypoint(lat=lat, lon=lon, alt=alt)], speed=GOTO_SPEED))
        assert reply.accepted, reply.reason
        kinds.append(_done(robot, reply.task_id, timeout_s, "goto ended"))
        reply = gcs.send(ROBOT, gri.Land())
        assert reply.accepted, reply.reason
        kinds.append(_done(robot, reply.task_id, timeout_s, "landing ended"))
        landed = robot.wait_state(lambda s: s.airborne is False, timeout_s, "on the ground")
        robot.wait_state(lambda s: s.stamp >= landed.stamp + watch_s, timeout_s,
                         f"{watch_s:g} simulated seconds of watching after the landing")
        end = robot.state
        return Flight(record=read_record(record), sim_s=end.stamp - sim0, wall_s=time.monotonic() - wall0,
                      events=kinds, cpu_s=cpu_by_process(la.pgid), home=(home.lat, home.lon, home.alt))
    finally:
        if gcs is not None:
            gcs.close()
        la.stop()
        la.cleanup()


def survey_manifest(tmp_path: Path) -> tuple[Path, Path]:
    """The shipped uav1_lidar_sim.toml in lockstep, its DSP simulator recording, the lidar logs in ``tmp_path``."""
    text = (ROOT / "bbcs_conf" / "uav1_lidar_sim.toml").read_text()
    text = text.replace('conf = "uav1.conf"', f'conf = "{ROOT / "bbcs_conf" / "uav1.conf"}"')
    record = tmp_path / "dsp.jsonl"
    dsp = '"--tcp", "127.0.0.1:{port:dsp}"'
    assert dsp + "]" in text, "the DSP simulator's command line in uav1_lidar_sim.toml changed"
    text = text.replace(dsp + "]", f'{dsp}, "--record", "{record}"]')
    text = text.replace("params = { ldmrs_host", f'params = {{ out_dir = "{tmp_path / "lidar"}", ldmrs_host')
    if "lockstep = true" not in text:
        text = text.replace("\n[bus]\n", "\n[sim]\nlockstep = true\n\n[bus]\n", 1)
    path = tmp_path / "uav1_lidar_sim.toml"
    path.write_text(text)
    return path, record


def fly_survey(tmp_path: Path, *, timeout_s: float = 300.0, survey: bool = True) -> Flight:
    """Take-off, the survey of the shipped area (``SURVEY_AREA``: 71 m x 89 m) at 25 m with 10 % overlap, landing,
    on uav1_lidar_sim.toml at ``--speed max``; ``survey=False``: take-off and landing only (bench/sim.py
    --smoke)."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    manifest, record = survey_manifest(tmp_path)
    la = Launch(manifest, tmp_path, "--speed", "max")
    gcs = None
    try:
        la.wait_line("modules up", 150)
        gcs = connect(la.port, "surveyor")
        robot = SimRobot(la, gcs, record)
        first = robot.wait_state(lambda s: s.link == "up" and s.position is not None and "survey" in s.available,
                                 timeout_s, "a GRI state with position and the survey task")
        wall0, sim0 = time.monotonic(), first.stamp
        kinds = []
        area = [t.Vertex(lat=lat, lon=lon) for lat, lon in read_polygon(SURVEY_AREA)]
        middle = [t.Survey(polygon=area, height=25.0, overlap=0.1)] if survey else []
        for task in (gri.TakeOff(height=10.0), *middle, gri.Land()):
            reply = gcs.send(ROBOT, task)
            assert reply.accepted, reply.reason
            kinds.append(_done(robot, reply.task_id, timeout_s, f"{type(task).__name__} ended"))
        landed = robot.wait_state(lambda s: s.airborne is False, timeout_s, "on the ground")
        return Flight(record=read_record(record), sim_s=landed.stamp - sim0, wall_s=time.monotonic() - wall0,
                      events=kinds, cpu_s=cpu_by_process(la.pgid))
    finally:
        if gcs is not None:
            gcs.close()
        la.stop()
        la.cleanup()
