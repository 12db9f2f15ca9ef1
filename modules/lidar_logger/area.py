"""The surveyed area for the terrain model: a GeoJSON polygon (the file the ground station's ``survey`` task
takes) in the DTM's local ENU frame, so coverage and holes are counted over the polygon, not the flight's box.
"""

from __future__ import annotations

import os

import numpy as np

from bbcs.geodesy import ecef_from_enu, lla_to_ecef
from bbcs.geojson import PolygonFileError, read_polygon


class AreaError(ValueError):
    """A polygon file that cannot be used; the message names the file."""


def load_polygon(path: str | os.PathLike[str]) -> np.ndarray:
    """(K, 2) latitude, longitude of a polygon file's outer ring, read by :func:`bbcs.geojson.read_polygon`."""
    try:
        return np.array(read_polygon(path), dtype=np.float64)
    except PolygonFileError as exc:
        raise AreaError(str(exc)) from None


def polygon_enu(latlon: np.ndarray, origin_lla: np.ndarray) -> np.ndarray:
    """(K, 2) east, north (m) of the vertices in the ENU frame at ``origin_lla`` (on the origin's height)."""
    lla = np.column_stack((latlon, np.full(len(latlon), float(origin_lla[2]))))
    enu = (lla_to_ecef(lla) - lla_to_ecef(np.asarray(origin_lla, dtype=np.float64))) @ ecef_from_enu(
        origin_lla[0], origin_lla[1])
    return enu[:, :2]
