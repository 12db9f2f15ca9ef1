"""The surveyed area for the terrain model: a GeoJSON polygon (the file the ground station's ``survey`` task
takes) in the DTM's local ENU frame, so coverage and holes are counted over the polygon, not the flight's box.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from modules.lidar_logger.geodesy import ecef_from_enu, lla_to_ecef


class AreaError(ValueError):
    """A polygon file that cannot be used; the message names the file."""


def load_polygon(path: str | os.PathLike[str]) -> np.ndarray:
    """(K, 2) latitude, longitude of the outer ring of a GeoJSON ``Polygon`` (or a ``Feature`` / one-feature
    ``FeatureCollection`` of one), ``[lon, lat]`` positions, the closing point dropped."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except OSError as exc:
        raise AreaError(f"{p}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise AreaError(f"{p}:{exc.lineno}: not valid JSON: {exc.msg}") from None
    geom = doc
    if isinstance(geom, dict) and geom.get("type") == "FeatureCollection":
        feats = geom.get("features") or []
        if len(feats) != 1:
            raise AreaError(f"{p}: a FeatureCollection must hold exactly one polygon, it holds {len(feats)}")
        geom = feats[0]
    if isinstance(geom, dict) and geom.get("type") == "Feature":
        geom = geom.get("geometry") or {}
    if not isinstance(geom, dict) or geom.get("type") != "Polygon" or not geom.get("coordinates"):
        raise AreaError(f"{p}: not a GeoJSON Polygon (or a Feature of one)")
    try:
        ring = np.array(geom["coordinates"][0], dtype=np.float64)
    except (TypeError, ValueError):
        raise AreaError(f"{p}: the polygon's ring is not a list of [lon, lat] positions") from None
    if ring.ndim != 2 or ring.shape[1] < 2:
        raise AreaError(f"{p}: the polygon's ring is not a list of [lon, lat] positions")
    if len(ring) > 1 and np.array_equal(ring[0], ring[-1]):
        ring = ring[:-1]
    latlon = ring[:, [1, 0]]
    if len(latlon) < 3:
        raise AreaError(f"{p}: a polygon needs 3 vertices, it has {len(latlon)}")
    if not (np.all(np.isfinite(latlon)) and np.all(np.abs(latlon[:, 0]) <= 90) and np.all(np.abs(latlon[:, 1]) <= 180)):
        raise AreaError(f"{p}: a vertex is not a valid [lon, lat] position")
    return latlon


def polygon_enu(latlon: np.ndarray, origin_lla: np.ndarray) -> np.ndarray:
    """(K, 2) east, north (m) of the vertices in the ENU frame at ``origin_lla`` (on the origin's height)."""
    lla = np.column_stack((latlon, np.full(len(latlon), float(origin_lla[2]))))
    enu = (lla_to_ecef(lla) - lla_to_ecef(np.asarray(origin_lla, dtype=np.float64))) @ ecef_from_enu(
        origin_lla[0], origin_lla[1])
    return enu[:, :2]
