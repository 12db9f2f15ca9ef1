"""Waypoint files for ``cromat gcs task ROBOT goto FILE``: CSV (``lat,lon,alt``) or GeoJSON.

Errors name the file and, for CSV, the line; a file with any bad point is refused whole.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import msgspec

from bbcs.contracts import gri

_LAT = {"lat", "latitude", "latitud"}
_LON = {"lon", "lng", "long", "longitude", "longitud"}
_ALT = {"alt", "altitude", "height", "altura"}


class WaypointFileError(ValueError):
    pass


def _point(lat: object, lon: object, alt: object, where: str) -> gri.Waypoint:
    try:
        return msgspec.convert({"lat": lat, "lon": lon, "alt": alt}, gri.Waypoint, strict=False)
    except msgspec.ValidationError as exc:
        raise WaypointFileError(f"{where}: bad waypoint: {exc}") from None


def load_csv(path: Path) -> list[gri.Waypoint]:
    """Rows ``lat,lon,alt`` (degrees, degrees, metres); an optional header row names the columns."""
    points: list[gri.Waypoint] = []
    order = (0, 1, 2)
    with path.open(newline="") as f:
        for lineno, row in enumerate(csv.reader(f), start=1):
            cells = [c.strip() for c in row]
            if not cells or not any(cells) or cells[0].startswith("#"):
                continue
            names = [c.lower() for c in cells]
            if not points and order == (0, 1, 2) and set(names) & (_LAT | _LON | _ALT):
                try:
                    order = tuple(
                        next(i for i, n in enumerate(names) if n in group)  # type: ignore[assignment]
                        for group in (_LAT, _LON, _ALT)
                    )
                except StopIteration:
                    raise WaypointFileError(
                        f"{path}:{lineno}: header must name lat, lon and alt columns"
                    ) from None
                continue
            if len(cells) < 3:
                raise WaypointFileError(f"{path}:{lineno}: expected lat,lon,alt, got {len(cells)} column(s)")
            points.append(_point(*(cells[i] for i in order), where=f"{path}:{lineno}"))
    return points


def _coords(obj: dict, path: Path) -> list[list[float]]:
    kind = obj.get("type")
    if kind == "FeatureCollection":
        return [c for feat in obj.get("features", []) for c in _coords(feat, path)]
    if kind == "Feature":
        return _coords(obj.get("geometry") or {}, path)
    if kind == "Point":
        return [obj["coordinates"]]
    if kind in ("LineString", "MultiPoint"):
        return list(obj["coordinates"])
    raise WaypointFileError(
        f"{path}: GeoJSON {kind!r} is not a Point, LineString, MultiPoint or a Feature of them"
    )


def load_geojson(path: Path) -> list[gri.Waypoint]:
    """GeoJSON positions are ``[lon, lat, alt]``; altitude is required."""
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise WaypointFileError(f"{path}:{exc.lineno}: not valid JSON: {exc.msg}") from None
    points = []
    for i, c in enumerate(_coords(doc, path)):
        if not isinstance(c, list) or len(c) < 3:
            raise WaypointFileError(f"{path}: position {i} must be [lon, lat, alt], got {c!r}")
        points.append(_point(c[1], c[0], c[2], where=f"{path}: position {i}"))
    return points


def load_waypoints(path: str | Path) -> list[gri.Waypoint]:
    p = Path(path)
    if not p.is_file():
        raise WaypointFileError(f"{p}: no such waypoint file")
    points = load_geojson(p) if p.suffix.lower() in (".geojson", ".json") else load_csv(p)
    if not points:
        raise WaypointFileError(f"{p}: no waypoints")
    return points


def load_polygon(path: str | Path) -> list[gri.Vertex]:
    """A survey polygon: the outer ring of a GeoJSON ``Polygon`` (or a ``Feature`` / one-feature
    ``FeatureCollection`` holding one), ``[lon, lat]`` positions, the closing point dropped."""
    p = Path(path)
    if not p.is_file():
        raise WaypointFileError(f"{p}: no such polygon file")
    try:
        doc = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise WaypointFileError(f"{p}:{exc.lineno}: not valid JSON: {exc.msg}") from None
    geom = doc
    if isinstance(geom, dict) and geom.get("type") == "FeatureCollection":
        feats = geom.get("features") or []
        if len(feats) != 1:
            raise WaypointFileError(f"{p}: a FeatureCollection must hold exactly one polygon, it holds {len(feats)}")
        geom = feats[0]
    if isinstance(geom, dict) and geom.get("type") == "Feature":
        geom = geom.get("geometry") or {}
    if not isinstance(geom, dict) or geom.get("type") != "Polygon" or not geom.get("coordinates"):
        kind = geom.get("type") if isinstance(geom, dict) else type(geom).__name__
        raise WaypointFileError(f"{p}: GeoJSON {kind!r} is not a Polygon (or a Feature of one)")
    ring = list(geom["coordinates"][0])
    if len(ring) > 1 and ring[0] == ring[-1]:
        ring = ring[:-1]
    vertices = []
    for i, c in enumerate(ring):
        if not isinstance(c, list) or len(c) < 2:
            raise WaypointFileError(f"{p}: vertex {i} must be [lon, lat], got {c!r}")
        try:
            vertices.append(msgspec.convert({"lat": c[1], "lon": c[0]}, gri.Vertex))
        except msgspec.ValidationError as exc:
            raise WaypointFileError(f"{p}: vertex {i}: {exc}") from None
    if len(vertices) < 3:
        raise WaypointFileError(f"{p}: a polygon needs at least 3 vertices, it has {len(vertices)}")
    return vertices
