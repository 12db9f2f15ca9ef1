"""The ground station's fleet input and the RAL's translation of a share: bad input is refused with a message
naming the target (or the area's file), an area may come as a GeoJSON Polygon file, a share becomes an ordinary
goto through its targets in order."""

from __future__ import annotations

import json
import time
from pathlib import Path

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts import tasks as t
from bbcs.contracts.fleet import FleetTarget, FleetTask
from bbcs.signing import FleetTrust, verify
from bbcs.testing import wait_until
from cromat import certs
from ral.fleet import can_do_from, goto_of
from ral.fleet_gcs import parse_area_arg, parse_target
from ral.fleet_protocol import Execute
from ral.gcs import cli
from ral.survey_area import area_targets


def test_targets_parse_with_kind_and_a_deadline_from_now() -> None:
    x = parse_target("t1, 37.41, -6.0, 22, inspect, 60", 0, now=1000.0)
    assert (x.id, x.lat, x.lon, x.alt, x.kind, x.deadline) == ("t1", 37.41, -6.0, 22.0, "inspect", 1060.0)
    assert parse_target("t2,37.41,-6.0,22", 1, now=0.0).kind == "visit"


@pytest.mark.parametrize("text, why", [
    ("t1,37.41,-6.0", "expected ID,LAT,LON,ALT"),
    ("t1,91,-6.0,22", "--target 1 't1,91,-6.0,22'"),
    ("t/1,37.41,-6.0,22", "--target 1"),
    ("t1,north,-6.0,22", "could not convert"),
])
def test_bad_targets_are_refused_naming_which(text: str, why: str) -> None:
    with pytest.raises(ValueError, match=why):
        parse_target(text, 0, now=0.0)


def test_a_task_without_targets_or_with_a_bad_id_does_not_decode() -> None:
    with pytest.raises(msgspec.ValidationError):
        msgspec.convert({"id": "a b", "targets": [{"id": "t", "lat": 1, "lon": 1, "alt": 1}]}, FleetTask)
    with pytest.raises(msgspec.ValidationError):
        msgspec.convert({"id": "a", "targets": []}, FleetTask)


def test_a_share_is_a_goto_through_its_targets_in_order() -> None:
    a = FleetTarget(id="a", lat=37.0, lon=-6.0, alt=20.0)
    b = FleetTarget(id="b", lat=37.1, lon=-6.1, alt=25.0)
    goto = goto_of(Execute(task=FleetTask(id="x", targets=[a, b], speed=4.0), round=2, targets=(b, a)))
    assert goto == t.Goto(waypoints=[t.Waypoint(lat=37.1, lon=-6.1, alt=25.0), t.Waypoint(lat=37.0, lon=-6.0,
                                                                                         alt=20.0)], speed=4.0)


def test_what_a_robot_bids_on() -> None:
    assert can_do_from("", ["goto", "land"]) == {"visit"}
    assert can_do_from("", ["land"]) == frozenset()
    assert can_do_from("visit, inspect", []) == {"visit", "inspect"}
    assert can_do_from("none", ["goto"]) == frozenset()


FIELD = [(37.4112, -6.0022), (37.4112, -6.0003), (37.4122, -6.0003), (37.4122, -6.0022)]


def _polygon_file(tmp_path: Path, corners: list[tuple[float, float]], name: str = "field.geojson") -> Path:
    ring = [[lon, lat] for lat, lon in [*corners, corners[0]]]
    path = tmp_path / name
    path.write_text(json.dumps({"type": "Feature", "properties": {},
                                "geometry": {"type": "Polygon", "coordinates": [ring]}}))
    return path


def test_an_area_from_a_geojson_polygon_is_the_same_as_from_its_corners(tmp_path: Path) -> None:
    corners = ";".join(f"{lat},{lon}" for lat, lon in FIELD)
    from_file = parse_area_arg(f"field;22;60;{_polygon_file(tmp_path, FIELD)}", 0)
    assert from_file == parse_area_arg(f"field;22;60;{corners}", 0) == area_targets("field", FIELD, 22.0, 60.0)
    assert len(from_file) == 6


@pytest.mark.parametrize(("content", "why"), [
    (None, "no such polygon file"),
    ('{"type": "LineString", "coordinates": [[-6.0, 37.41], [-5.999, 37.41]]}', "is not a Polygon"),
    ('{"type": "Polygon", "coordinates": [[[-6.0, 97.0], [-5.999, 37.41], [-5.999, 37.411]]]}', "vertex 0"),
    ("{not json", "not valid JSON"),
])
def test_a_bad_polygon_file_is_refused_naming_the_argument_and_the_file(tmp_path: Path, content: str | None,
                                                                          why: str) -> None:
    path = tmp_path / "bad.geojson"
    if content is not None:
        path.write_text(content)
    with pytest.raises(ValueError, match=why) as err:
        parse_area_arg(f"field;22;60;{path}", 1)
    assert "--area 2" in str(err.value) and "bad.geojson" in str(err.value)


def test_cromat_gcs_fleet_post_sends_an_area_file_s_cells_and_nothing_for_a_bad_file(
        router: int, clients, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Over a real router: the task on the bus holds the file's cells; a bad file exits 2 and puts nothing (the
    marker published after it is the first thing the listener gets)."""
    listener = clients(router)
    got: list[bytes] = []
    sub = listener.declare_subscriber(keys.fleet_task_key("*"), lambda s: got.append(s.payload.to_bytes()))
    try:
        base = ["--connect", f"tcp/127.0.0.1:{router}", "--name", "poster", "fleet", "post", "--wait", "0.5"]
        bad = tmp_path / "bad.geojson"
        bad.write_text('{"type": "Point", "coordinates": [-6.0, 37.41]}')
        assert cli.main([*base, "--id", "bad", "--area", f"bad;22;60;{bad}"]) == 2
        assert "bad.geojson" in capsys.readouterr().out
        clients(router).put(keys.fleet_task_key("marker"), b"marker")
        wait_until(lambda: got, 10, "the marker")
        assert got == [b"marker"], "nothing was posted for the bad file"
        assert cli.main([*base, "--id", "field", "--area", f"field;22;60;{_polygon_file(tmp_path, FIELD)}"]) == 3
        wait_until(lambda: len(got) == 2, 10, "the posted task")
        task = msgspec.msgpack.decode(got[1], type=FleetTask)
        assert task.id == "field" and task.balance and task.targets == area_targets("field", FIELD, 22.0, 60.0)
    finally:
        sub.undeclare()


def test_cromat_gcs_fleet_post_signs_with_the_station_s_certificate_and_refuses_a_key_not_its_own(
        router: int, clients, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Over a real router: with ``--cert``/``--key`` the task on the bus carries the station's certificate and a
    signature that verifies (bbcs/signing.py); a key that is not the certificate's exits 2 and puts nothing. The
    task names the robots whose RAL is alive even before their fleet state reached the station (a clean-clone run
    signed a task for the one robot whose state had arrived, and the other refused it), and the station says
    which robot never answered."""
    (tmp_path / "ca").mkdir()
    certs.make_ca(tmp_path / "ca")
    for name in ("gcs", "other"):
        certs.make_leaf(tmp_path / "ground", name, ca_dir=tmp_path / "ca")
    ground = tmp_path / "ground"
    listener = clients(router)
    got: list[bytes] = []
    sub = listener.declare_subscriber(keys.fleet_task_key("*"), lambda s: got.append(s.payload.to_bytes()))
    token = clients(router).liveliness().declare_token(keys.alive_key("uav09", "ral"))  # alive, no fleet state
    try:
        base = ["--connect", f"tcp/127.0.0.1:{router}", "--name", "poster", "--cert", str(ground / "gcs.pem")]
        post = ["fleet", "post", "--wait", "0.5", "--target", "t0,37.41,-6.0,22"]
        assert cli.main([*base, "--key", str(ground / "other.key"), *post, "--id", "mismatched"]) == 2
        assert "is not the key of" in capsys.readouterr().out
        clients(router).put(keys.fleet_task_key("marker"), b"marker")
        wait_until(lambda: got, 10, "the marker")
        assert got == [b"marker"], "nothing was posted with a key that is not the certificate's"
        assert cli.main([*base, "--key", str(ground / "gcs.key"), *post, "--id", "signed"]) == 3
        assert "answered []" in capsys.readouterr().out
        wait_until(lambda: len(got) == 2, 10, "the posted task")
        task = msgspec.msgpack.decode(got[1], type=FleetTask)
        trust = FleetTrust.from_files(tmp_path / "ca" / "ca.pem", ["gcs"])
        assert task.id == "signed" and verify(task, trust, time.time()) == "gcs"
        assert task.robots == ["uav09"]
    finally:
        token.undeclare()
        sub.undeclare()
