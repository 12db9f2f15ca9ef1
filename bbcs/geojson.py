"""The one GeoJSON polygon reader: the ground station's survey and no-fly-zone files and the logger's terrain area
are the same files, so they are read, and refused, the same way.

A polygon file is a ``Polygon``, or a ``Feature`` / one-feature ``FeatureCollection`` holding one; its outer ring
of ``[lon, lat]`` positions (GeoJSON order) is returned as (lat, lon) vertices, the closing point dropped.
Every error names the file.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from bbcs.geodesy import check_lla


class PolygonFileError(ValueError):
    """A polygon file that cannot be used; the message names the file (and the vertex or JSON line)."""


def read_polygon(path: str | os.PathLike[str]) -> list[tuple[float, float]]:
    """(lat, lon) vertices of the file's outer ring: at least 3, each inside the contracts' ranges."""
    p = Path(path)
    if not p.is_file():
        raise PolygonFileError(f"{p}: no such polygon file")
    try:
        doc = json.loads(p.read_text())
    except OSError as exc:
        raise PolygonFileError(f"{p}: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        where = f":{exc.lineno}" if isinstance(exc, json.JSONDecodeError) else ""
        raise PolygonFileError(f"{p}{where}: not valid JSON: {getattr(exc, 'msg', exc)}") from None
    geom = doc
    if isinstance(geom, dict) and geom.get("type") == "FeatureCollection":
        feats = geom.get("features") or []
        if len(feats) != 1:
            raise PolygonFileError(f"{p}: a FeatureCollection must hold exactly one polygon, it holds {len(feats)}")
        geom = feats[0]
    if isinstance(geom, dict) and geom.get("type") == "Feature":
        geom = geom.get("geometry") or {}
    if not isinstance(geom, dict) or geom.get("type") != "Polygon" or not geom.get("coordinates"):
        kind = geom.get("type") if isinstance(geom, dict) else type(geom).__name__
        raise PolygonFileError(f"{p}: GeoJSON {kind!r} is not a Polygon (or a Feature of one)")
    ring = geom["coordinates"][0]
    if not isinstance(ring, list):
        raise PolygonFileError(f"{p}: the polygon's ring is not a list of [lon, lat] positions")
    if len(ring) > 1 and ring[0] == ring[-1]:
        ring = ring[:-1]
    vertices: list[tuple[float, float]] = []
    for i, c in enumerate(ring):
        if not (isinstance(c, list) and len(c) >= 2 and all(isinstance(v, int | float) for v in c[:2])):
            raise PolygonFileError(f"{p}: vertex {i} must be [lon, lat], got {c!r}")
        lat, lon = float(c[1]), float(c[0])
        try:
            check_lla(lat, lon)
        except ValueError as exc:
            raise PolygonFileError(f"{p}: vertex {i} is not a valid [lon, lat] position: {exc}") from None
        vertices.append((lat, lon))
    if len(vertices) < 3:
        raise PolygonFileError(f"{p}: a polygon needs at least 3 vertices, it has {len(vertices)}")
    return vertices
