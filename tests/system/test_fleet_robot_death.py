"""Issue 30 case 9: ``cromat fleet`` with two UAVs of the shipped ``uav1_sim.toml``; a ground station on the hub
takes them off and posts a target north of each home; ``kill -9`` of uav02's Module Manager before it got there.
The launcher says which robot went down and why, and keeps uav01 flying (its manager alive, its GRI answering);
the fleet re-allocates uav02's target to uav01, whose DSP simulator receives it and which visits it.

The fleet runs in lockstep (``[fleet] lockstep = true``, ``speed`` = ``FLEET_PACE``: docs/simulation.md, "A fleet in
lockstep"): uav01's simulator steps both robots, and steps on alone once uav02's members are gone; the kill lands
at a step the test holds (``StepGate``), and the re-allocation is timed on the robots' clock."""

from __future__ import annotations

import os
import signal
import sys
from contextlib import ExitStack
from pathlib import Path

import pytest

from bbcs.lockstep import current_time
from bbcs.session import open_session
from bbcs.testing import StepGate, wait_until
from ral.fleet_gcs import FleetView
from ral.gcs.api import Gcs, session_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fleet_support import FLEET_PACE, ROOT, fleet_run  # noqa: E402
from test_fleet_alloc import FLEET_SPEED, cli_post, take_off_all  # noqa: E402
from test_fleet_scale import records  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "module_manager"))
from launch_support import group_members  # noqa: E402

NAMES = ["uav01", "uav02"]


def fleet_manifest(tmp: Path) -> Path:
    """Two robots of the shipped uav1_sim.toml, as bbcs_conf/fleet10_sim.toml makes ten."""
    shipped = (ROOT / "bbcs_conf" / "fleet10_sim.toml").read_text()
    assert "robots = 10" in shipped and 'manifest = "uav1_sim.toml"' in shipped
    path = tmp / "fleet2.toml"
    path.write_text(shipped.replace("robots = 10", f"robots = 2\nlockstep = true\nspeed = {FLEET_PACE}").replace(
        'manifest = "uav1_sim.toml"', f'manifest = "{ROOT / "bbcs_conf" / "uav1_sim.toml"}"'))
    return path


def manager_pid(leader: int, name: str) -> int:
    """The pid of robot ``name``'s ``cromat launch`` (module_manager.cli with its run-dir manifest)."""
    for pid in group_members(leader):
        try:
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"module_manager.cli" in argv and any(a.endswith(f"/{name}/{name}.toml".encode()) for a in argv):
            return pid
    raise AssertionError(f"no launch of {name} among the fleet's processes")


@pytest.mark.timeout(300)
def test_a_robot_killed_mid_task_leaves_the_others_flying_and_its_target_reallocated(tmp_path: Path) -> None:
    run = tmp_path / "run"
    with fleet_run(fleet_manifest(tmp_path), run) as fleet, ExitStack() as closing:
        hub = fleet.hub_port(2, 180)
        gcs = closing.enter_context(Gcs(session_config([f"tcp/127.0.0.1:{hub}"]), name="ground", link=NAMES,
                                        timeout_s=10.0))
        wait_until(lambda: gcs.robots(1.0) == NAMES, 60, "both robots seen from the hub")
        take_off_all(gcs, NAMES)
        session = closing.enter_context(open_session(session_config([f"tcp/127.0.0.1:{hub}"])))
        view = FleetView(session)
        closing.callback(view.close)
        victim = manager_pid(fleet.proc.pid, "uav02")
        survivor = manager_pid(fleet.proc.pid, "uav01")
        where = {}
        for name, cells in (("uav01", 2), ("uav02", 6)):  # uav02's ~67 m away: not reached before the kill
            home = gcs.state(name).home
            assert home is not None
            where[f"{name}_t"] = (round(home.lat + cells * 1e-4, 4), round(home.lon, 4), home.alt + 10.0)
        done = cli_post(hub, "death", [f"{t},{lat},{lon},{alt}" for t, (lat, lon, alt) in where.items()],
                        speed=FLEET_SPEED)
        assert done.returncode == 0 and "agreed by 2 robots" in done.stdout, done.stdout + done.stderr
        first = view.wait(lambda: view.agreed("death", set(NAMES)), 20)
        assert first is not None and first.routes == {"uav01": ["uav01_t"], "uav02": ["uav02_t"]}, first

        gate = StepGate(session, "uav01")
        closing.callback(gate.leave)
        with gate.closed():  # the kill at one simulated instant, before uav02 can reach its target
            killed = current_time(session, "uav01")
            assert killed is not None
            os.kill(victim, signal.SIGKILL)
            line = fleet.wait_line(lambda x: "fleet: robot uav02 is down" in x, 20, "the launcher naming uav02")
        assert "killed by SIGKILL" in line and "1 of 2 robots fly on (uav01)" in line, line
        assert "uav02_t" not in view.visited("death"), "uav02 got there before the kill: nothing to re-allocate"
        after = view.wait(lambda: (d := view.agreed("death", {"uav01"})) is not None and d.round >= 1 and d, 60)
        assert after and after.routes["uav01"] and "uav02_t" in after.routes["uav01"], view.decisions("death")
        print(f"re-allocated {after.decided - killed.epoch - killed.t:.2f} simulated s after the kill")
        wait_until(lambda: view.visited("death") >= {"uav01_t", "uav02_t"}, 90, "both targets visited by uav01")
        assert where["uav02_t"][:2] in set(records(run, "uav01")), "uav02's target never reached uav01's DSP"

        # the survivor flew on all along: its launch, its GRI; the launcher neither stopped nor restarted anything
        assert fleet.proc.poll() is None and not any("fleet stopped" in x for x in fleet.lines)
        os.kill(survivor, 0)
        assert gcs.state("uav01", 5.0).manager_up
        wait_until(lambda: gcs.robots(1.0) == ["uav01"], 20, "uav02's RAL gone from the bus")
