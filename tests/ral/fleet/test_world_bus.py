"""The world model on real Zenoh (ral/world_bus.py): RALs' world nodes behind one router, each its own session.

An edit through one reaches the others; a late joiner gets the whole model; an update a node missed is recovered
by the digest exchange; vision targets and completed surveys become entries; tracking follows a target."""

from __future__ import annotations

import msgspec

from bbcs import keys
from bbcs.contracts import gri, mri
from bbcs.contracts import tasks as t
from bbcs.contracts import world as w
from bbcs.contracts.pan_tilt import DatosPT
from bbcs.testing import wait_until
from ral.world_bus import fetch_snapshots

LAT, LON = 37.41, -6.0


def square(half: float = 0.001) -> list[t.Vertex]:
    return [t.Vertex(lat=LAT - half, lon=LON - half), t.Vertex(lat=LAT - half, lon=LON + half),
            t.Vertex(lat=LAT + half, lon=LON + half), t.Vertex(lat=LAT + half, lon=LON - half)]


def ask(session, robot: str, payload: bytes) -> w.WorldReply:
    for reply in session.get(w.world_request_key(robot), payload=payload, timeout=10.0):
        if reply.ok is not None:
            return msgspec.msgpack.decode(reply.ok.payload.to_bytes(), type=w.WorldReply)
    raise AssertionError("no reply")


def test_edits_spread_late_joiners_catch_up_and_missed_updates_are_recovered(nodes, router: int, clients) -> None:
    a, b = nodes("uav_a"), nodes("uav_b")
    gcs = clients(router)
    reply = ask(gcs, "uav_a", msgspec.msgpack.encode(w.WorldPut(id="mast", body=w.NoFlyZone(polygon=square()),
                                                                author="ground")))
    assert reply.accepted and reply.entry is not None and reply.entry.version == 1 and reply.entry.origin == "uav_a"
    wait_until(lambda: b.get("mast") == reply.entry, 10, "the zone at uav_b")
    assert b.refusal(t.Goto(waypoints=[t.Waypoint(lat=LAT, lon=LON, alt=50.0)])) is not None

    late = nodes("uav_c")  # started after the edit: asks every RAL for its model
    wait_until(lambda: late.get("mast") == reply.entry, 10, "the zone at the late joiner")

    with a.lock:  # an update uav_b and uav_c never heard (as if published during a partition)
        missed = a.model.put("field", w.Geofence(polygon=square(0.01)), origin="uav_a", stamp=1.0)
    wait_until(lambda: b.get("field") == missed and late.get("field") == missed, 10, "recovered by digests")
    wait_until(lambda: len({n.snapshot().digest for n in (a, b, late)}) == 1, 10, "one model everywhere")

    gone = ask(gcs, "uav_b", msgspec.msgpack.encode(w.WorldDelete(id="mast", author="ground")))
    assert gone.accepted and gone.entry is not None and gone.entry.deleted and gone.entry.version == 2
    wait_until(lambda: a.get("mast") is None and late.get("mast") is None, 10, "the removal everywhere")
    again = ask(gcs, "uav_b", msgspec.msgpack.encode(w.WorldDelete(id="mast")))
    assert not again.accepted and "no world entry 'mast'" in again.reason
    bad = ask(gcs, "uav_b", b"\x81\xa4type\xa4nope")
    assert not bad.accepted and "invalid world request" in bad.reason
    snaps = {snap.robot: snap for snap in fetch_snapshots(gcs)}
    assert sorted(snaps) == ["uav_a", "uav_b", "uav_c"] and len({x.digest for x in snaps.values()}) == 1


def test_vision_targets_and_completed_surveys_become_entries_and_a_tracker_follows(nodes, router: int,
                                                                                   clients) -> None:
    pointed: list[tuple[float, float, int]] = []
    started: list[t.TaskParams] = []

    def start_task(task: t.TaskParams) -> gri.TaskReply:
        started.append(task)
        return gri.TaskReply(accepted=True, task_id=41, task_type="pan_tilt")

    def point_at(target: w.Target, task_id: int) -> bool:
        pointed.append((target.lat, target.lon, task_id))
        return True

    nodes("uav_a")
    b = nodes("uav_b", start_task=start_task, point_at=point_at)
    vision = clients(router)
    key = keys.slot_key("uav_a", "vision", "target")
    vision.put(key, msgspec.msgpack.encode(DatosPT(latitud=LAT, longitud=LON, altura=12.0)))
    wait_until(lambda: b.get("target.uav_a") is not None, 10, "uav_a's target at uav_b")
    entry = b.get("target.uav_a")
    assert entry is not None and entry.body == w.Target(lat=LAT, lon=LON, alt=12.0, seen_by="uav_a", seen_at=1000.0)

    reply = b.request(w.TrackTarget(target="target.uav_a"))
    assert reply.accepted and reply.task_id == 41
    assert started == [t.LookAt(lat=LAT, lon=LON, alt=12.0)]
    vision.put(key, msgspec.msgpack.encode(DatosPT(latitud=LAT + 0.001, longitud=LON, altura=12.0)))  # 111 m
    wait_until(lambda: (LAT + 0.001, LON, 41) in pointed, 10, "the tracker pointed at the moved target")
    assert not b.request(w.TrackTarget(target="target.nobody")).accepted

    survey = t.Survey(polygon=square(), height=30.0)
    state = mri.RobotState(robot="uav_a", kind="uav", stamp=0.0, ended=[
        t.TaskInfo(id=7, name="survey", task_type="movement", params=survey, status="completed"),
        t.TaskInfo(id=8, name="survey", task_type="movement", params=survey, status="failed")])
    vision.put(mri.mri_key("uav_a", mri.STATE), msgspec.msgpack.encode(state))
    wait_until(lambda: b.get("surveyed.uav_a.7") is not None, 10, "the surveyed area at uav_b")
    assert b.get("surveyed.uav_a.8") is None
    body = b.get("surveyed.uav_a.7").body
    assert isinstance(body, w.Surveyed) and body.by == "uav_a" and body.polygon == survey.polygon


def test_gcs_world_commands_show_add_and_refuse_bad_files(nodes, router: int, tmp_path, capsys) -> None:
    import json

    from ral.gcs import cli

    a = nodes("uav_a")
    base = ["--connect", f"tcp/127.0.0.1:{router}", "--name", "ground", "--timeout", "10", "world"]
    ring = [[v.lon, v.lat] for v in square()]
    zone = tmp_path / "old town.geojson"
    zone.write_text(json.dumps({"type": "Polygon", "coordinates": [[*ring, ring[0]]]}))
    assert cli.main([*base, "add-nfz", "uav_a", str(zone), "--label", "old town"]) == 0
    assert "added old_town (version 1)" in capsys.readouterr().out
    entry = a.get("old_town")
    assert entry is not None and entry.author == "ground" and entry.body == w.NoFlyZone(polygon=square(),
                                                                                           name="old town")
    assert cli.main([*base, "show", "uav_a"]) == 0
    shown = capsys.readouterr().out
    assert "world of uav_a: 1 entries" in shown and "old_town" in shown and "no-fly   4 vertices (old town)" in shown
    line = tmp_path / "line.geojson"
    line.write_text(json.dumps({"type": "LineString", "coordinates": ring}))
    assert cli.main([*base, "add-nfz", "uav_a", str(line)]) == 2
    assert "is not a Polygon" in capsys.readouterr().err
    assert cli.main([*base, "remove", "uav_a", "nothing"]) == 1
    assert "no world entry 'nothing'" in capsys.readouterr().out
    assert len(a.snapshot().entries) == 1
