"""Issue 17, scale: ``cromat fleet bbcs_conf/fleet10_sim.toml`` runs ten simulated UAVs on this machine (each its
router, Module Manager, modules and DSP simulator), meshed in a star; a ground station on the hub router sees
all ten, takes them off and posts twenty targets; the ten RALs agree on one allocation, each robot's own two
targets, and every target is flown by the robot that won it (its DSP simulator's record), and by no other.

About 80 processes: it takes a 2-core machine's two cores for about a minute, so it is one of the heavy files
(tests/conftest.py's ``HEAVY_STACKS``) that one xdist worker runs one after another, the first of them, and it is
marked ``alone``: it starts once the other workers have finished their current test files, and they start no
other file until it is done (beside it, their deadlines were missed).
"""

from __future__ import annotations

import sys
from contextlib import ExitStack
from pathlib import Path

import pytest

from bbcs.session import open_session
from bbcs.testing import wait_until
from module_manager.fleet import load_fleet
from ral.fleet_gcs import FleetView
from ral.gcs.api import Gcs, session_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fleet_support import ROOT, fleet_run  # noqa: E402
from test_fleet_alloc import FLEET_SPEED, cli_post, take_off_all  # noqa: E402

from modules.dsp.sim.record import read_record

FLEET = ROOT / "bbcs_conf" / "fleet10_sim.toml"


def records(run: Path, name: str) -> list[tuple[float, float]]:
    lines = read_record(run / name / "dsp_record.jsonl")
    return [(round(c["fields"]["lat"], 4), round(c["fields"]["lon"], 4)) for c in lines if c["name"] == "ADD_WAYPOINT"]


@pytest.mark.alone  # ten stacks starve any test beside them (tests/conftest.py): under xdist it runs by itself
@pytest.mark.timeout(600)
def test_ten_robots_from_a_fleet_manifest_allocate_twenty_targets(tmp_path: Path) -> None:
    spec = load_fleet(FLEET)
    names = [spec.name.format(n=n) for n in range(1, spec.robots + 1)]
    run = tmp_path / "run"
    with fleet_run(FLEET, run) as fleet, ExitStack() as closing:
        hub = fleet.hub_port(10, 300)
        gcs = closing.enter_context(Gcs(session_config([f"tcp/127.0.0.1:{hub}"]), name="ground", link=names,
                                        timeout_s=10.0))
        wait_until(lambda: gcs.robots(1.0) == names, 60, "all ten robots seen from the hub")
        take_off_all(gcs, names)
        session = closing.enter_context(open_session(session_config([f"tcp/127.0.0.1:{hub}"])))
        view = FleetView(session)
        closing.callback(view.close)

        # twenty targets on the grid, two by each robot's home (north and south of it, ~33 m away; homes are 60 m
        # apart). Posted balanced (the last robot done soonest, as a user sharing work expects): each robot's own
        # two. Unbalanced, the least total flight would have one robot chain the southern row of targets alone.
        targets, where = [], {}
        for name in names:
            st = gcs.state(name)
            assert st.home is not None
            for k, dn in enumerate((3, -3)):  # on the DSP's waypoint grid (1e-4 degree, ADD_WAYPOINT)
                lat, lon = round(st.home.lat + dn * 1e-4, 4), round(st.home.lon, 4)
                tid = f"{name}_{k}"
                targets.append(f"{tid},{lat},{lon},{st.home.alt + 10.0}")
                where[tid] = (lat, lon)
        # ten robot stacks keep both cores busy: the CLI's own start and the agreement take longer than elsewhere
        done = cli_post(hub, "sweep", targets, timeout_s=150.0, balance=True, wait_s=90.0, speed=FLEET_SPEED)
        assert done.returncode == 0, done.stdout + done.stderr
        assert "agreed by 10 robots" in done.stdout, done.stdout
        dec = view.wait(lambda: view.agreed("sweep", set(names)), 20)
        assert dec is not None and dec.bidders == names, view.decisions("sweep")
        assert sorted(t for r in dec.routes.values() for t in r) == sorted(where)
        assert {r: sorted(ts) for r, ts in dec.routes.items()} == {n: [f"{n}_0", f"{n}_1"] for n in names}, dec.routes
        wait_until(lambda: view.visited("sweep") == set(where), 240, "all twenty targets visited")
        for name in names:
            got = set(records(run, name))
            mine = {where[t] for t in dec.routes[name]}
            theirs = {where[t] for r, ts in dec.routes.items() if r != name for t in ts} - mine
            assert mine <= got and not theirs & got, (name, dec.routes[name], got)
