"""Terrain model: the ground filter and plane fit on hand-made points, coverage and holes, and a simulated
flight turned into a GeoTIFF by ``cromat lidar dtm`` and checked against the simulator's analytic terrain."""

from __future__ import annotations

import json
import warnings

import laspy
import numpy as np
import pytest
import rasterio
import rasterio.errors

from modules.lidar_logger import cli
from modules.lidar_logger.dtm import Dtm, build_dtm, coverage, ground_candidates, hillshade, polygon_mask
from modules.lidar_logger.flags import FLAG_DIRT, FLAG_GROUND, FLAG_RAIN, FLAG_TRANSPARENT
from modules.lidar_logger.sim import LdmrsOptions, World
from modules.lidar_logger.sim.survey_flight import flight_scans, write_run


def test_ground_candidates_follow_the_scanner_flags() -> None:
    flags = np.array([0, FLAG_GROUND, FLAG_DIRT, FLAG_RAIN, FLAG_TRANSPARENT | FLAG_RAIN, FLAG_GROUND | FLAG_DIRT])
    assert ground_candidates(flags).tolist() == [True, True, False, False, False, False]


def test_plane_fit_is_exact_on_a_slope_and_the_filter_drops_points_above() -> None:
    rng = np.random.default_rng(1)
    e, n = rng.uniform(0, 10, 4000), rng.uniform(0, 10, 4000)
    z = 5 + 0.4 * e - 0.3 * n
    canopy = rng.random(4000) < 0.1  # a tenth of the points 2-8 m above the ground
    z_obs = np.where(canopy, z + rng.uniform(2, 8, 4000), z)
    dtm = build_dtm(np.column_stack((e, n, z_obs)), 2.0, bounds=(0, 0, 10, 10))
    ce, cn = dtm.centres()
    assert dtm.shape == (5, 5)
    assert np.abs(dtm.z - (5 + 0.4 * ce - 0.3 * cn)).max() < 1e-9
    assert dtm.count.sum() == (~canopy).sum()


def test_cells_whose_points_do_not_pin_a_plane_use_their_block_and_empty_cells_stay_empty() -> None:
    def plane(e, n):
        return 1.0 + 0.5 * e + 0.2 * n

    en = np.array([[0.5, 0.5], [0.2, 0.7],                 # south-west cell: two points
                   [1.1, 0.1], [1.5, 0.5], [1.9, 0.9],     # south-east cell: three on a line
                   [0.1, 1.1], [0.9, 1.2], [0.5, 1.9]])    # north-west cell: enough; north-east: none
    pts = np.column_stack((en, plane(en[:, 0], en[:, 1])))
    dtm = build_dtm(pts, 1.0, bounds=(0, 0, 2, 2))
    ce, cn = dtm.centres()
    assert np.isnan(dtm.z[0, 1])  # no point there: nothing is interpolated into it
    has = ~np.isnan(dtm.z)
    assert has.sum() == 3 and np.allclose(dtm.z[has], plane(ce[has], cn[has]))
    assert dtm.count.tolist() == [[3, 0], [2, 3]]
    lone = build_dtm(np.array([[0.5, 0.5, 1.0], [0.6, 0.4, 1.0]]), 1.0, bounds=(0, 0, 1, 1))
    assert np.isnan(lone.z).all()  # two points and no neighbours: no plane at all


def test_bad_cell_size_is_refused() -> None:
    with pytest.raises(ValueError, match="cell size"):
        build_dtm(np.zeros((3, 3)), 0.0)


def test_coverage_counts_holes_enclosed_by_data_only() -> None:
    z = np.ones((6, 6))
    z[2:4, 2:4] = np.nan          # a hole of 4 cells
    z[0, 5] = np.nan               # an empty cell on the edge: not a hole
    z[5, 0] = np.nan
    cov = coverage(Dtm(z, np.ones_like(z, dtype=np.int64), 0.0, 6.0, 1.0))
    assert (cov.cells, cov.with_data, cov.holes, cov.hole_cells) == (36, 30, 1, 4)
    assert cov.percent == pytest.approx(100 * 30 / 36)


def test_polygon_mask_selects_cell_centres_inside() -> None:
    dtm = Dtm(np.zeros((4, 4)), np.zeros((4, 4), dtype=np.int64), 0.0, 4.0, 1.0)
    mask = polygon_mask(dtm, np.array([[0, 0], [2, 0], [2, 4], [0, 4]]))
    assert mask[:, :2].all() and not mask[:, 2:].any()


def test_hillshade_marks_no_data_zero_and_lights_slopes_facing_the_sun() -> None:
    e = np.arange(5.0)
    z = np.tile(e, (5, 1))  # rising to the east: faces west, towards a sun in the north-west
    z2 = np.tile(-e, (5, 1))
    z2[0, 0] = np.nan
    a = hillshade(Dtm(z, np.zeros((5, 5), dtype=np.int64), 0, 5, 1.0))
    b = hillshade(Dtm(z2, np.zeros((5, 5), dtype=np.int64), 0, 5, 1.0))
    assert a[2, 2] > b[2, 2] > 0 and b[0, 0] == 0


@pytest.fixture(scope="module")
def flight_folder(tmp_path_factory):
    world = World()
    records = list(flight_scans(world, LdmrsOptions(return_fraction=1.0, seed=3), t_start=20.0, n_scans=150))
    folder = write_run(tmp_path_factory.mktemp("flight") / "Scan_sim", world, records)
    return world, folder


def test_cromat_lidar_dtm_matches_the_analytic_terrain(flight_folder, tmp_path, capsys) -> None:
    world, folder = flight_folder
    tif, png, laz = tmp_path / "dtm.tif", tmp_path / "dtm.png", tmp_path / "ground.laz"
    code = cli.main(["dtm", str(folder), "--cell", "2", "--out", str(tif), "--hillshade", str(png),
                     "--las", str(laz), "--json"])
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    with rasterio.open(tif) as ds:
        heights = ds.read(1).astype(np.float64)
        assert ds.res == (2.0, 2.0) and ds.crs is not None and ds.nodata == -9999.0
        origin = np.array([float(ds.tags()[k]) for k in ("ORIGIN_LAT", "ORIGIN_LON", "ORIGIN_H")])
        t = ds.transform
    has = heights != -9999.0
    assert has.sum() == report["cells_with_data"] > 2000
    rows, cols = np.nonzero(has)
    enu = np.column_stack((t.c + (cols + 0.5) * 2.0, t.f - (rows + 0.5) * 2.0, heights[has] - origin[2]))
    terrain = world.enu_to_terrain(enu, origin)
    err = terrain[:, 2] - world.terrain.height(terrain[:, 0], terrain[:, 1])
    assert np.sqrt(np.mean(err**2)) < 0.03 and np.abs(err).max() < 0.15
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(png) as ds:
                shade = ds.read(1)
        assert shade.shape == heights.shape and (shade[has] > 0).all() and (shade[~has] == 0).all()
    cloud = laspy.read(laz)
    assert len(cloud.points) == report["points"] and set(np.unique(cloud.classification)) == {2}


def test_two_logs_go_into_one_model(flight_folder, tmp_path, capsys) -> None:
    world, folder = flight_folder
    records = list(flight_scans(world, LdmrsOptions(return_fraction=1.0, seed=4), t_start=40.0, n_scans=60))
    second = write_run(tmp_path / "Scan_sim2", world, records)
    assert cli.main(["dtm", str(folder), str(second), "--cell", "4", "--out", str(tmp_path / "a.tif"),
                     "--json"]) == 0
    said = capsys.readouterr()
    both = json.loads(said.out)
    assert [line.split(" reading")[0] for line in said.err.splitlines()][:2] == [  # progress (issue 34 item 8)
        "cromat lidar dtm: 1/2", "cromat lidar dtm: 2/2"]
    assert "cromat lidar dtm: gridding" in said.err
    assert cli.main(["dtm", str(folder), "--cell", "4", "--out", str(tmp_path / "b.tif"), "--json"]) == 0
    one = json.loads(capsys.readouterr().out)
    assert both["logs"] == 2 and both["points"] > one["points"] and both["cells_with_data"] > one["cells_with_data"]


def test_georef_writes_las(flight_folder, tmp_path) -> None:
    _, folder = flight_folder
    assert cli.main(["georef", str(folder), "--out", str(tmp_path / "cloud.las")]) == 0
    cloud = laspy.read(tmp_path / "cloud.las")
    assert len(cloud.points) > 100_000 and cloud.header.scales.tolist() == [0.001, 0.001, 0.001]


def test_a_bad_cell_size_is_a_usage_error(flight_folder, tmp_path, capsys) -> None:
    _, folder = flight_folder
    assert cli.main(["dtm", str(folder), "--cell", "-1", "--out", str(tmp_path / "x.tif")]) == 2
    assert "--cell must be positive" in capsys.readouterr().err and not (tmp_path / "x.tif").exists()
