"""``cromat lidar dtm --picture``: a terrain map a person can read, judged from the PNG read back: its size, the
polygon outline where the polygon is, the colour ramp and its legend, the scale bar's length in metres, the north
arrow."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
import rasterio.errors

from modules.lidar_logger import cli, picture
from modules.lidar_logger.dtm import Dtm
from modules.lidar_logger.raster import write_png

WEST, NORTH, CELL = 100.0, 300.0, 2.0
ROWS, COLS = 60, 90  # 180 m east-west, 120 m north-south
POLYGON = np.array([[130.0, 270.0], [250.0, 260.0], [240.0, 200.0], [140.0, 210.0]])


def read_png(path: Path) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(path) as ds:
            return np.moveaxis(ds.read(), 0, -1)


def plane() -> Dtm:
    """Heights rising 0.1 m per metre eastwards from 50 m, a hole of no data in the middle."""
    east = WEST + (np.arange(COLS) + 0.5) * CELL
    z = np.tile(50.0 + 0.1 * (east - WEST), (ROWS, 1))
    z[25:30, 40:45] = np.nan
    return Dtm(z, np.ones((ROWS, COLS), dtype=np.int64), WEST, NORTH, CELL)


def segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return np.hypot(*(p - (a + t[:, None] * ab)).T)


@pytest.fixture(scope="module")
def drawn(tmp_path_factory: pytest.TempPathFactory) -> tuple[picture.Picture, np.ndarray, Dtm]:
    dtm = plane()
    pic = picture.draw(dtm, POLYGON)
    path = write_png(tmp_path_factory.mktemp("pic") / "map.png", pic.image)
    return pic, read_png(path), dtm


def test_size_and_north_up_map(drawn) -> None:
    pic, img, dtm = drawn
    assert img.shape == pic.image.shape and img.dtype == np.uint8 and img.shape[2] == 3
    assert max(img.shape[:2]) >= 800, "at least 800 pixels on the long side"
    r0, c0, r1, c1 = pic.map_box
    assert (c1 - c0, r1 - r0) == (COLS * pic.scale, ROWS * pic.scale)
    hole = pic.image[r0 + 27 * pic.scale, c0 + 42 * pic.scale]
    assert tuple(hole) == picture.NO_DATA


def test_outline_lies_on_the_polygon_and_goes_all_round(drawn) -> None:
    pic, img, dtm = drawn
    rows, cols = np.nonzero(np.all(img == picture.OUTLINE, axis=-1))
    assert len(rows) > 500
    en = np.array([pic.pixel_to_en(r, c, dtm) for r, c in zip(rows, cols, strict=True)])
    edges = list(zip(POLYGON, np.roll(POLYGON, -1, axis=0), strict=True))
    nearest = np.min([segment_distance(en, a, b) for a, b in edges], axis=0)
    metres_per_pixel = CELL / pic.scale
    assert nearest.max() <= 2.5 * metres_per_pixel, "every outline pixel within its 3-pixel stroke of an edge"
    for a, b in edges:  # and every edge drawn from end to end
        for t in np.linspace(0.0, 1.0, 9):
            p = a + t * (b - a)
            assert np.hypot(*(en - p).T).min() <= metres_per_pixel


def test_colour_ramp_and_its_legend(drawn) -> None:
    pic, img, dtm = drawn
    lo, hi = pic.heights
    assert lo == pytest.approx(50.1) and hi == pytest.approx(50.0 + 0.1 * (COLS - 0.5) * CELL)
    r0, c0, r1, c1 = pic.legend_box
    bar = img[r0:r1, (c0 + c1) // 2].astype(float)
    assert len({tuple(c) for c in bar}) > 50, "a ramp, not a few flat colours"
    assert np.allclose(bar[0], picture.ramp(np.array(1.0)), atol=1) and np.allclose(bar[-1], picture.ramp(
        np.array(0.0)), atol=1), "the highest at the top, the lowest at the bottom"
    # the map's colours follow the legend: on the plane (one slope, one shade) the west edge has the bottom's hue,
    # the east edge the top's
    m0, mc0, _, mc1 = pic.map_box
    row = m0 + 5 * pic.scale
    for col, legend in ((mc0 + 1, bar[-1]), (mc1 - 2, bar[0])):
        got = img[row, col].astype(float)
        cos = got @ legend / (np.linalg.norm(got) * np.linalg.norm(legend))
        assert cos > 0.995, (got, legend)
    assert picture.draw(dtm, height_offset=140.0).heights == pytest.approx((lo + 140.0, hi + 140.0))
    labels = img[r0 - 10:r1 + 10, c1 + 8:]  # the heights written beside the bar
    assert (np.all(labels == 0, axis=-1)).sum() > 100


def test_scale_bar_is_as_long_as_it_says(drawn) -> None:
    pic, img, dtm = drawn
    assert pic.scale_bar_m == 50.0  # 180 m wide: a third is 60 m, the nicest length below is 50 m
    r0, c0, r1, c1 = pic.scale_bar_box
    mid = img[(r0 + r1) // 2, c0 - 3:c1 + 3]
    dark = np.nonzero(np.all(mid == 0, axis=-1))[0]
    span_px = dark.max() - dark.min() + 1 - 2  # less its frame, one pixel each side
    assert span_px * CELL / pic.scale == pytest.approx(50.0, abs=CELL / pic.scale)
    white = np.all(mid[dark.min():dark.max()] == 255, axis=-1).sum()
    assert white > span_px // 3, "alternate black and white segments"


def test_north_arrow_points_up(drawn) -> None:
    pic, img, _ = drawn
    r0, c0, r1, c1 = pic.arrow_box
    ink = np.all(img[r0:r1, c0:c1] == 0, axis=-1)
    widths = ink[ink.any(axis=1)].sum(axis=1)
    assert ink.sum() > 300
    assert widths[-1] > 3 * widths[len(widths) // 2 - 4], "narrow at the top, wide at the bottom"


def test_nice_lengths() -> None:
    assert [picture.nice_length(x) for x in (0.7, 1.0, 3.2, 60.0, 999.0)] == [0.5, 1.0, 2.0, 50.0, 500.0]


def test_cromat_lidar_dtm_writes_the_picture(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from modules.lidar_logger.sim import LdmrsOptions, World
    from modules.lidar_logger.sim.survey_flight import flight_scans, write_run

    world = World()
    records = list(flight_scans(world, LdmrsOptions(return_fraction=1.0, seed=5), t_start=20.0, n_scans=60))
    folder = write_run(tmp_path / "Scan_sim", world, records)
    png = tmp_path / "map.png"
    assert cli.main(["dtm", str(folder), "--cell", "2", "--out", str(tmp_path / "dtm.tif"), "--picture", str(png),
                     "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["picture"] == str(png)
    img = read_png(png)
    assert max(img.shape[:2]) >= 800 and img.shape[2] == 3
    with rasterio.open(tmp_path / "dtm.tif") as ds:
        heights = ds.read(1)
    cells = heights[heights != ds.nodata]
    scale = picture.draw(Dtm(np.where(heights == ds.nodata, np.nan, heights).astype(float),
                             np.zeros(heights.shape, dtype=np.int64), 0.0, 0.0, 2.0)).scale
    assert img.shape[1] == picture.MARGIN + report["cols"] * scale + picture.PANEL
    assert len(cells) == report["cells_with_data"]
