"""Lockstep on the shipped uav1_sim.toml (docs/simulation.md): the same mission gives the same DSP record on a
quiet machine and beside 4 busy processes, and nothing the ground station did not ask for follows the landing.

The record compared is the command sequence and fields, as the simulated DSP applied them once simulated time
moved (its times are not the contract: a ground station's request reaches the robot at whatever simulated time its
wall clock allows). What reaches the DSP at time 0, while the robot starts, is not ordered by any step: the
pan & tilt module's first SET_PT_MODE is lost when it publishes before the DSP module has subscribed (seen once in
three launches, lockstep or not), so only the start-up sequence is checked there."""

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
    mission = [name for name, _ in quiet.commands()]
    assert mission.count("SET_MODE") == 3 and "ADD_WAYPOINT" in mission, mission  # take-off, goto, land went out
    for flight in (quiet, loaded):  # the start-up sequence in its order, before simulated time moved
        names = [name for name, _ in flight.startup()]
        assert names[:7] == ["SET_SPEED", "SET_TELEMETRY_MASK", "SET_STATE_TX", "CLEAR_ERROR", "SET_TRACKING",
                             "INVALIDATE_PATH", "SET_HELI_TYPE"], names
    assert quiet.commands() == loaded.commands(), (
        "the DSP records differ:\n" + "\n".join(f"{a}\n{b}\n" for a, b in zip(quiet.commands(), loaded.commands(),
                                                                                strict=False) if a != b))
    # nothing unrequested after the landing: its SET_MODE(LANDING) is the last command, 20 simulated s later
    assert quiet.record[-1]["name"] == "SET_MODE" and quiet.record[-1]["fields"]["mode"] == int(p.Mode.LANDING)
    print(f"quiet: {quiet.sim_s:.1f} s simulated in {quiet.wall_s:.1f} s ({quiet.sim_s / quiet.wall_s:.2f}x); "
          f"4 busy processes: {loaded.sim_s:.1f} s in {loaded.wall_s:.1f} s ({loaded.sim_s / loaded.wall_s:.2f}x)")
