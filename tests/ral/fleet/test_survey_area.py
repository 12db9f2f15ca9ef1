"""An area to survey becomes fleet targets (ral/survey_area.py): the centres of a grid inside the polygon, which
cover it; bad areas are refused saying why; and the fleet's auction splits the cells among the robots, each
robot taking the block near it (the protocol's simulated network of tests/ral/fleet/test_fleet_protocol.py)."""

from __future__ import annotations

import math
import random
import sys
from pathlib import Path

import pytest

from bbcs.contracts.fleet import MAX_TARGETS, FleetTask
from bbcs.geodesy import LocalFrame
from ral.survey_area import AreaError, area_targets, parse_area
from ral.world_geometry import inside, project

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_fleet_protocol import LAT0, LON0, Net  # noqa: E402

FRAME = LocalFrame(LAT0, LON0)


def corner(north_m: float, east_m: float) -> tuple[float, float]:
    """The point ``north_m``/``east_m`` metres from (LAT0, LON0) in the project's geodesy, which the grid uses."""
    lat, lon, _ = FRAME.to_geo(east_m, north_m)
    return lat, lon


W, H = 299.5, 199.5
"""The field: just under 6 × 4 spacings of 50 m east-west × north-south (a side of exactly a whole number of
spacings leaves the cell count to rounding; the sphere this test was first written on made it 299.7 × 199.4 m)."""
FIELD = [corner(0, 0), corner(0, W), corner(H, W), corner(H, 0)]


def xy(targets) -> list[tuple[float, float]]:
    return project([(t.lat, t.lon) for t in targets], LAT0, LON0)


def test_a_rectangle_becomes_a_grid_of_cells_that_covers_it() -> None:
    cells = area_targets("field", FIELD, 40.0, 50.0)
    assert len(cells) == 6 * 4
    assert [c.id for c in cells] == [f"field.{n}" for n in range(24)]
    assert {(c.alt, c.kind) for c in cells} == {(40.0, "visit")}
    pts = xy(cells)
    poly = project(FIELD, LAT0, LON0)
    assert all(inside(p, poly) for p in pts)
    nearest = [min(math.dist(p, q) for q in pts if q is not p) for p in pts]
    assert max(abs(d - 50.0) for d in nearest) < 0.5, "neighbours one spacing apart"
    rng = random.Random(3)  # every point of the field is within half a cell's diagonal of a cell centre
    for _ in range(500):
        p = (rng.uniform(0, W), rng.uniform(0, H))
        assert min(math.dist(p, q) for q in pts) <= 50.0 * math.sqrt(2) / 2 + 0.5
    assert pts[5][0] > pts[0][0] and pts[6][0] > pts[11][0], "rows alternate direction (a lawnmower order)"


def test_a_concave_area_has_no_cell_in_its_notch() -> None:
    s, h = H, H / 2  # a 4 × 4-cell square, less its north-east quarter
    ell = [corner(0, 0), corner(0, s), corner(h, s), corner(h, h), corner(s, h), corner(s, 0)]
    cells = area_targets("ell", ell, 40.0, 50.0)
    pts = xy(cells)
    assert len(cells) == 12  # 16 cells of the 200 m square, less the 4 in the missing quarter
    assert not [p for p in pts if p[0] > 100 and p[1] > 100]


@pytest.mark.parametrize("polygon, spacing, why", [
    (FIELD[:2], 50.0, "at least 3 corners"),
    ([corner(0, 0), corner(0, 100), corner(0, 200)], 50.0, "enclose no ground"),
    ([corner(0, 0), corner(100, 100), corner(0, 100), corner(100, 0)], 10.0, "edges 1 and 3 cross"),
    (FIELD, 0.0, "positive number of metres"),
    (FIELD, 5.0, f"more than a fleet task's {MAX_TARGETS} targets; use a spacing of about 18 m"),
    (FIELD, 1.0, "more than a fleet task's"),
    ([corner(0, 0), corner(0, 100), corner(10, 100), corner(10, 10), corner(100, 10), corner(100, 0)], 200.0,
     "no cell centre"),
])
def test_bad_areas_are_refused_saying_why(polygon, spacing: float, why: str) -> None:
    with pytest.raises(AreaError, match=why):
        area_targets("a", polygon, 40.0, spacing)


def test_the_command_line_form_and_its_errors() -> None:
    text = ";".join(["field", "40", "50"] + [f"{lat},{lon}" for lat, lon in FIELD])
    assert parse_area(text, 0) == area_targets("field", FIELD, 40.0, 50.0)
    for bad, why in [("field;40;50;37.4,-6.0;37.5,-6.0", "3 corners or more"),
                     ("field;40;50;37.4,-6.0;37.5;37.5,-6.1;37.4,-6.1", "--area 1"),
                     ("field;40;50;95,-6.0;37.5,-6.0;37.5,-6.1", "corner 1"),
                     ("field;high;50;37.4,-6.0;37.5,-6.0;37.5,-6.1", "could not convert"),
                     ("f/x;40;50;" + ";".join(f"{lat},{lon}" for lat, lon in FIELD), "area 'f/x'")]:
        with pytest.raises(ValueError, match=why):
            parse_area(bad, 0)


def test_the_fleet_splits_an_area_each_robot_taking_the_cells_near_it() -> None:
    cells = area_targets("field", FIELD, 40.0, 50.0)
    task = FleetTask(id="survey_field", targets=cells, balance=True)
    at = {"west": (100.0, -60.0), "east": (100.0, 360.0), "north": (260.0, 150.0)}
    net = Net(at)
    net.nodes["north"].post(task, net.now)
    net.run(3.0)
    digests = net.digests("survey_field")
    assert len(set(digests.values())) == 1 and None not in digests.values(), digests
    dec = net.nodes["west"].decision("survey_field")
    assert dec is not None and not dec.unassigned
    assert sorted(t for r in dec.routes.values() for t in r) == sorted(c.id for c in cells)
    where = dict(zip([c.id for c in cells], xy(cells), strict=True))
    home = {r: (e, n) for r, (n, e) in at.items()}
    for robot, route in dec.routes.items():
        assert route, f"{robot} got no share of the area"
        own = sum(math.dist(home[robot], where[t]) for t in route) / len(route)
        others = [t for r, ts in dec.routes.items() if r != robot for t in ts]
        theirs = sum(math.dist(home[robot], where[t]) for t in others) / len(others)
        assert own < theirs, (robot, own, theirs)
