"""How far a terrain model is from the simulator's analytic terrain: the error ``cromat lidar dtm`` makes on a
simulated flight.

    python -m modules.lidar_logger.sim.terrain_check dtm.tif [--polygon area.geojson] [--origin LAT LON ALT]

The GeoTIFF's cell centres (its local transverse Mercator = the ENU frame of its origin, tags ``ORIGIN_*``)
are taken into the terrain frame (anchored at ``--origin``; default the DSP simulator's home, where
``uav1_lidar_sim.toml`` anchors it) and compared with h(e, n); cells with data inside the polygon (default:
all) count. Prints (or returns) cells, RMS, p99, max and mean error in metres.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence

import numpy as np

from modules.lidar_logger.area import load_polygon, polygon_enu
from modules.lidar_logger.dtm import Dtm, polygon_mask
from modules.lidar_logger.sim.world import Terrain, World

DSP_HOME = (37.4117, -6.0025, 12.0)
"""The DSP simulator's default home (``python -m modules.dsp.sim --home``)."""


def dtm_error(geotiff: str | os.PathLike[str], *, polygon: Sequence[tuple[float, float]] | None = None,
              terrain_origin: tuple[float, float, float] = DSP_HOME, terrain: Terrain | None = None
              ) -> dict[str, float]:
    import rasterio

    with rasterio.open(geotiff) as ds:
        z = ds.read(1).astype(np.float64)
        z[z == ds.nodata] = np.nan
        tr, tags = ds.transform, ds.tags()
    origin = np.array([float(tags["ORIGIN_LAT"]), float(tags["ORIGIN_LON"]), float(tags["ORIGIN_H"])])
    dtm = Dtm(z=z - origin[2], count=np.zeros(z.shape, dtype=np.int64), west=tr.c, north=tr.f, cell=tr.a)
    area = np.ones(z.shape, dtype=bool) if polygon is None else polygon_mask(
        dtm, polygon_enu(np.asarray(polygon, dtype=np.float64), origin))
    e, n = dtm.centres()
    sel = area & np.isfinite(dtm.z)
    world = World(origin_lla=tuple(terrain_origin), **({"terrain": terrain} if terrain else {}))
    enu = np.column_stack((e[sel], n[sel], dtm.z[sel]))
    pts = world.enu_to_terrain(enu, origin)
    err = pts[:, 2] - world.terrain.height(pts[:, 0], pts[:, 1])
    if not len(err):
        return {"cells": 0, "rms_m": float("nan"), "p99_m": float("nan"), "max_m": float("nan"),
                "mean_m": float("nan")}
    return {"cells": int(len(err)), "rms_m": float(np.sqrt(np.mean(err**2))),
            "p99_m": float(np.percentile(np.abs(err), 99)), "max_m": float(np.abs(err).max()),
            "mean_m": float(err.mean())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m modules.lidar_logger.sim.terrain_check",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("geotiff")
    ap.add_argument("--polygon", help="GeoJSON polygon: only the cells inside count")
    ap.add_argument("--origin", type=float, nargs=3, metavar=("LAT", "LON", "ALT"), default=DSP_HOME,
                    help="where the simulator anchored its terrain (default the DSP simulator's home)")
    args = ap.parse_args(argv)
    polygon = [tuple(v) for v in load_polygon(args.polygon)] if args.polygon else None
    print(json.dumps(dtm_error(args.geotiff, polygon=polygon, terrain_origin=tuple(args.origin))))  # type: ignore[arg-type]
    return 0


if __name__ == "__main__":
    sys.exit(main())
