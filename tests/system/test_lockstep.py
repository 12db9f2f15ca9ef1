"""Lockstep on the shipped uav1_sim.toml (docs/simulation.md): the same mission gives the same DSP record on a
quiet machine and beside 4 busy processes, and nothing the ground station did not ask for follows the landing.

The record compared is the command sequence and fields, as the simulated DSP applied them (its times are not
the contract: a ground station's request reaches the robot at whatever simulated time its wall clock allows)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from modules.dsp import protocol as p

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lockstep_support import busy_processes, fly_mission, stop  # noqa: E402


@pytest.mark.timeout(600)
def test_the_same_mission_gives_the_same_dsp_record_at_any_load(tmp_path: Path) -> None:
    quiet = fly_mission(tmp_path / "quiet")
    hogs = busy_processes(4)
    try:
        loaded = fly_mission(tmp_path / "loaded")
    finally:
        stop(hogs)
    assert quiet.events == loaded.events == ["task_completed"] * 3
    names = [name for name, _ in quiet.commands()]
    mission = names[names.index("SET_PT_MODE") + 1:]
    assert mission.count("SET_MODE") == 3 and "ADD_WAYPOINT" in mission, mission  # take-off, goto, land went out
    assert quiet.commands() == loaded.commands(), (
        "the DSP records differ:\n" + "\n".join(f"{a}\n{b}\n" for a, b in zip(quiet.commands(), loaded.commands(),
                                                                                strict=False) if a != b))
    # nothing unrequested after the landing: its SET_MODE(LANDING) is the last command, 20 simulated s later
    assert quiet.record[-1]["name"] == "SET_MODE" and quiet.record[-1]["fields"]["mode"] == int(p.Mode.LANDING)
    print(f"quiet: {quiet.sim_s:.1f} s simulated in {quiet.wall_s:.1f} s ({quiet.sim_s / quiet.wall_s:.2f}x); "
          f"4 busy processes: {loaded.sim_s:.1f} s in {loaded.wall_s:.1f} s ({loaded.sim_s / loaded.wall_s:.2f}x)")
