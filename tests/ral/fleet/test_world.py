"""The world model, pure (ral/world.py, ral/world_geometry.py): deterministic merge, what it refuses, targets."""

from __future__ import annotations

import itertools
import random

import msgspec
import pytest

from bbcs.contracts import tasks as t
from bbcs.contracts import world as w
from bbcs.contracts.geo import GeoPoint
from ral import world
from ral import world_geometry as g

LAT, LON = 37.41, -6.00
D = 0.001  # ~111 m north, ~88 m east


def square(lat: float, lon: float, half: float) -> list[t.Vertex]:
    return [t.Vertex(lat=lat - half, lon=lon - half), t.Vertex(lat=lat - half, lon=lon + half),
            t.Vertex(lat=lat + half, lon=lon + half), t.Vertex(lat=lat + half, lon=lon - half)]


def nfz(half: float = D) -> w.NoFlyZone:
    return w.NoFlyZone(polygon=square(LAT, LON, half), name="tower")


def wp(lat: float, lon: float) -> t.Waypoint:
    return t.Waypoint(lat=lat, lon=lon, alt=50.0)


def test_merge_is_order_independent_and_idempotent() -> None:
    a, b = world.WorldModel(), world.WorldModel()
    e1 = a.put("zone", nfz(), origin="uav_a", stamp=1.0)
    e2 = b.put("zone", nfz(2 * D), origin="uav_b", stamp=0.5)  # concurrent: same id, same version
    e3 = a.put("other", nfz(), origin="uav_a", stamp=2.0)
    e4 = a.delete("other", origin="uav_a", stamp=3.0)
    assert e4 is not None and e4.deleted and e4.version == 2
    updates = [e1, e2, e3, e4]
    digests = set()
    for order in itertools.permutations(updates):
        m = world.WorldModel()
        for entry in [*order, *random.Random(1).sample(updates, 4)]:  # and again: duplicates change nothing
            m.merge(entry)
        digests.add(m.digest())
        assert m.get("zone") == e2  # version tie: the greater origin wins, everywhere
        assert m.get("other") is None and len(m) == 2
    assert len(digests) == 1


def test_a_later_version_wins_and_a_local_edit_takes_the_next_version() -> None:
    m = world.WorldModel()
    first = m.put("zone", nfz(), origin="uav_b", stamp=1.0)
    remote = msgspec.structs.replace(first, version=5, origin="uav_a", body=nfz(3 * D))
    assert m.merge(remote) and m.get("zone") == remote
    assert not m.merge(first)  # older: no change
    nxt = m.put("zone", nfz(), origin="uav_b", stamp=2.0, author="ground")
    assert nxt.version == 6 and nxt.author == "ground"
    assert m.delete("missing", origin="uav_b", stamp=3.0) is None


def test_waypoints_inside_or_legs_across_a_no_fly_zone_are_refused_with_the_zone_named() -> None:
    m = world.WorldModel()
    m.put("tower", nfz(), origin="uav_a", stamp=0.0, author="ground1")
    inside = t.Goto(waypoints=[wp(LAT + 5 * D, LON), wp(LAT, LON + 0.5 * D)])
    why = world.refusal(m, inside)
    assert why is not None and "waypoint 1" in why and "no-fly zone 'tower'" in why and "ground1 via uav_a" in why
    across = t.FollowPath(waypoints=[wp(LAT - 3 * D, LON), wp(LAT + 3 * D, LON)])
    why = world.refusal(m, across)
    assert why is not None and "leg from waypoint 0 to waypoint 1 crosses" in why
    first_leg = t.Goto(waypoints=[wp(LAT + 3 * D, LON)])
    assert world.refusal(m, first_leg) is None
    why = world.refusal(m, first_leg, position=GeoPoint(lat=LAT - 3 * D, lon=LON, alt=20.0))
    assert why is not None and "from the robot's position" in why
    caught_inside = GeoPoint(lat=LAT, lon=LON, alt=20.0)  # a zone added around a flying robot: it may leave
    assert world.refusal(m, first_leg, position=caught_inside) is None
    assert world.refusal(m, t.Goto(waypoints=[wp(LAT, LON + 0.5 * D)]), position=caught_inside) is not None
    clear = t.Goto(waypoints=[wp(LAT + 3 * D, LON + 3 * D), wp(LAT - 3 * D, LON + 3 * D)])
    assert world.refusal(m, clear, position=GeoPoint(lat=LAT, lon=LON + 5 * D, alt=20.0)) is None
    assert world.refusal(m, t.TakeOff()) is None and world.refusal(m, t.LookAt(lat=LAT, lon=LON, alt=1.0)) is None


def test_areas_overlapping_a_zone_and_points_outside_every_geofence_are_refused() -> None:
    m = world.WorldModel()
    m.put("tower", nfz(), origin="uav_a", stamp=0.0)
    survey = t.Survey(polygon=square(LAT + 1.5 * D, LON, D), height=30.0)
    assert "area overlaps no-fly zone" in (world.refusal(m, survey) or "")
    assert "overlaps" in (world.refusal(m, t.Orbit(lat=LAT, lon=LON + 2 * D, radius=120.0)) or "")
    assert world.refusal(m, t.Orbit(lat=LAT, lon=LON + 3 * D, radius=50.0)) is None
    m.put("field", w.Geofence(polygon=square(LAT, LON, 10 * D)), origin="uav_b", stamp=0.0)
    assert "outside every geofence" in (world.refusal(m, t.Goto(waypoints=[wp(LAT + 20 * D, LON)])) or "")
    assert world.refusal(m, t.Goto(waypoints=[wp(LAT + 5 * D, LON)])) is None
    m.delete("tower", origin="uav_b", stamp=1.0)
    assert world.refusal(m, survey) is None


def test_geometry_edges_and_circle() -> None:
    sq = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)]
    assert g.inside((5.0, 5.0), sq) and g.inside((10.0, 5.0), sq) and not g.inside((10.1, 5.0), sq)
    assert g.leg_enters((-5.0, 5.0), (15.0, 5.0), sq) and not g.leg_enters((-5.0, 11.0), (15.0, 11.0), sq)
    assert g.segments_cross((0.0, 0.0), (2.0, 2.0), (0.0, 2.0), (2.0, 0.0))
    ring = g.project(g.circle(LAT, LON, 100.0), LAT, LON)
    assert all(r >= 100.0 for r in (abs(complex(*p)) for p in ring))


def test_vision_reports_become_a_target_entry_at_a_bounded_rate() -> None:
    m = world.WorldModel()
    first = world.target_entry(None, lat=LAT, lon=LON, alt=12.0, robot="uav_a", now=10.0)
    assert first == w.Target(lat=LAT, lon=LON, alt=12.0, seen_by="uav_a", seen_at=10.0)
    held = m.put(world.target_id("uav_a"), first, origin="uav_a", stamp=10.0)
    assert world.target_entry(held, lat=LAT + 1e-6, lon=LON, alt=12.0, robot="uav_a", now=10.5) is None
    assert world.target_entry(held, lat=LAT + 1e-4, lon=LON, alt=12.0, robot="uav_a", now=10.5) is not None
    assert world.target_entry(held, lat=LAT, lon=LON, alt=12.0, robot="uav_a", now=11.0) is not None
    assert world.target_entry(None, lat=float("nan"), lon=LON, alt=0.0, robot="uav_a", now=1.0) is None


def test_a_completed_survey_becomes_a_surveyed_area() -> None:
    survey = t.Survey(polygon=square(LAT, LON, D), height=30.0)
    done = t.TaskInfo(id=7, name="survey", task_type="movement", params=survey, status="completed")
    entry_id, body = world.surveyed_entry(done, "uav_b", 5.0) or ("", None)
    assert entry_id == "surveyed.uav_b.7" and body == w.Surveyed(polygon=survey.polygon, by="uav_b", at=5.0)
    assert world.surveyed_entry(msgspec.structs.replace(done, status="failed"), "uav_b", 5.0) is None


@pytest.mark.parametrize("bad", ["", "a/b", "x" * 70, "@adv"])
def test_entry_ids_are_key_safe(bad: str) -> None:
    with pytest.raises(msgspec.ValidationError):
        msgspec.convert({"id": bad, "version": 1, "origin": "a", "stamp": 0.0}, w.WorldEntry)
