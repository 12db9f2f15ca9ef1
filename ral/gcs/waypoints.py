"""Waypoint files for ``cromat gcs task ROBOT goto FILE``: CSV (``lat,lon,alt``) or GeoJSON.

Errors name the file and, for CSV, the line; a file with any bad point is refused whole.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import msgspec

from bbcs.contracts import gri
from bbcs.geojson import PolygonFileError, read_polygon

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
    """A survey or no-fly-zone polygon file, read by :func:`bbcs.geojson.read_polygon`, as GRI vertices."""
    try:
        return [gri.Vertex(lat=lat, lon=lon) for lat, lon in read_polygon(path)]
    except PolygonFileError as exc:
        raise WaypointFileError(str(exc)) from None
