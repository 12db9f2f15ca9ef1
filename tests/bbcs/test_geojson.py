"""The one GeoJSON polygon reader: what it accepts, and every refusal naming the file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bbcs.geojson import PolygonFileError, read_polygon

RING = [[-6.0, 37.41], [-5.999, 37.41], [-5.999, 37.411], [-6.0, 37.411], [-6.0, 37.41]]


def _write(path: Path, doc: object) -> Path:
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


@pytest.mark.parametrize("doc", [
    {"type": "Polygon", "coordinates": [RING]},
    {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [RING]}},
    {"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": {"type": "Polygon",
                                                                              "coordinates": [RING]}}]},
])
def test_a_polygon_feature_or_collection_gives_lat_lon_vertices_without_the_closing_point(tmp_path: Path,
                                                                                         doc: dict) -> None:
    got = read_polygon(_write(tmp_path / "a.geojson", doc))
    assert got == [(37.41, -6.0), (37.41, -5.999), (37.411, -5.999), (37.411, -6.0)]


@pytest.mark.parametrize(("doc", "why"), [
    (None, "no such polygon file"),
    ("{not json", ":1: not valid JSON"),
    ({"type": "LineString", "coordinates": RING}, "'LineString' is not a Polygon"),
    ({"type": "FeatureCollection", "features": []}, "exactly one polygon, it holds 0"),
    ({"type": "Polygon", "coordinates": [[[-6.0, 97.0], [-5.999, 37.41], [-5.999, 37.411]]]},
     r"vertex 0 is not a valid \[lon, lat\] position: latitude 97.0"),
    ({"type": "Polygon", "coordinates": [[[-6.0, 37.41], "x", [-5.999, 37.411]]]}, "vertex 1 must be"),
    ({"type": "Polygon", "coordinates": [[[-6.0, 37.41], [-5.999, 37.41], [-6.0, 37.41]]]}, "at least 3 vertices"),
])
def test_a_bad_file_is_refused_naming_it_and_why(tmp_path: Path, doc: object, why: str) -> None:
    path = tmp_path / "bad.geojson"
    if doc is not None:
        _write(path, doc)
    with pytest.raises(PolygonFileError, match=why) as err:
        read_polygon(path)
    assert str(err.value).startswith(str(path))
