"""Waypoint files: CSV and GeoJSON, with errors naming file and line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bbcs.contracts import gri
from ral.gcs.waypoints import WaypointFileError, load_waypoints


def test_csv_with_header_in_any_order(tmp_path: Path) -> None:
    f = tmp_path / "wp.csv"
    f.write_text("# mission\nalt,lon,lat\n30,-6.0,37.41\n35, -6.001 ,37.42\n")
    assert load_waypoints(f) == [
        gri.Waypoint(lat=37.41, lon=-6.0, alt=30.0),
        gri.Waypoint(lat=37.42, lon=-6.001, alt=35.0),
    ]


def test_csv_without_header(tmp_path: Path) -> None:
    f = tmp_path / "wp.csv"
    f.write_text("37.41,-6.0,30\n\n37.42,-6.0,30\n")
    assert len(load_waypoints(f)) == 2


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("37.41,-6.0,30\n91,-6.0,30\n", ":2: bad waypoint"),
        ("37.41,-6.0\n", ":1: expected lat,lon,alt"),
        ("37.41,abc,30\n", ":1: bad waypoint"),
        ("lat,lon,height,x\n1,2\n", ":2: expected"),
    ],
)
def test_csv_errors_name_the_line(tmp_path: Path, text: str, where: str) -> None:
    f = tmp_path / "wp.csv"
    f.write_text(text)
    with pytest.raises(WaypointFileError, match=f"wp.csv{where}"):
        load_waypoints(f)


def test_geojson_linestring_and_feature_collection(tmp_path: Path) -> None:
    line = tmp_path / "a.geojson"
    line.write_text(
        json.dumps(
            {
                "type": "Feature",
                "geometry": {
                    "type": "LineString",
                    "coordinates": [[-6.0, 37.41, 30.0], [-6.001, 37.42, 31.0]],
                },
            }
        )
    )
    assert load_waypoints(line)[1] == gri.Waypoint(lat=37.42, lon=-6.001, alt=31.0)
    points = tmp_path / "b.json"
    points.write_text(
        json.dumps(
            {
                "type": "FeatureCollection",
                "features": [
                    {"type": "Feature", "geometry": {"type": "Point", "coordinates": [-6.0, 37.4, 20.0]}}
                ]
                * 3,
            }
        )
    )
    assert len(load_waypoints(points)) == 3


@pytest.mark.parametrize(
    ("doc", "match"),
    [
        ({"type": "LineString", "coordinates": [[-6.0, 37.41]]}, "position 0 must be"),
        ({"type": "LineString", "coordinates": [[-6.0, 97.41, 3.0]]}, "position 0: bad waypoint"),
        ({"type": "Polygon", "coordinates": []}, "Polygon"),
    ],
)
def test_geojson_errors(tmp_path: Path, doc: dict, match: str) -> None:
    f = tmp_path / "x.geojson"
    f.write_text(json.dumps(doc))
    with pytest.raises(WaypointFileError, match=match):
        load_waypoints(f)


def test_missing_and_empty_files(tmp_path: Path) -> None:
    with pytest.raises(WaypointFileError, match="no such"):
        load_waypoints(tmp_path / "nope.csv")
    (tmp_path / "e.csv").write_text("# nothing\n")
    with pytest.raises(WaypointFileError, match="no waypoints"):
        load_waypoints(tmp_path / "e.csv")
