"""Zone edits signed by the ground station (bbcs/contracts/world.py ``StationEdit``, ral/world.py ``check_edit``,
ral/world_bus.py's gate), by attack. The decision, pure, with an injected time: a station-signed zone and removal
pass (also after msgpack, however they arrive as entries); a moved polygon, a removal signed for another id, an
addition's signature on a removal, a module's certificate, another CA's, no signature, a zone under a robot's own
id: refused, each with its reason; the robots' own entries need no signature. Then world nodes on real Zenoh: a
secured node applies only signed station requests, and drops forged zones and removals from a peer's update and a
peer's snapshot (counted, logged once, never relayed) while the same samples' robot entries arrive (the control);
``cromat gcs world`` signs with ``--cert``/``--key``. (Over a launched secured robot: tests/system/test_secure_mesh.py.)
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import msgspec
import pytest

from bbcs.contracts import tasks as t
from bbcs.contracts import world as w
from bbcs.contracts.signed import seal_of
from bbcs.signing import (
    BadSignature,
    FleetTrust,
    NotAGroundStation,
    SignatureRefused,
    StationSigner,
    Unsigned,
    UntrustedIssuer,
)
from bbcs.testing import wait_until
from cromat import certs
from ral import world
from ral.gcs.fleet_cmd import signed_request

LAT, LON = 37.41, -6.0


def square(half: float = 0.001, lat: float = LAT) -> list[t.Vertex]:
    return [t.Vertex(lat=lat - half, lon=LON - half), t.Vertex(lat=lat - half, lon=LON + half),
            t.Vertex(lat=lat + half, lon=LON + half), t.Vertex(lat=lat + half, lon=LON - half)]


ZONE = w.NoFlyZone(polygon=square(), name="mast")
INSIDE = t.Goto(waypoints=[t.Waypoint(lat=LAT, lon=LON, alt=50.0)])


@dataclass
class Pki:
    gcs: StationSigner
    module: StationSigner
    rogue: StationSigner
    trust: FleetTrust
    now: float
    ground: Path


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    root = tmp_path_factory.mktemp("world-signed")
    for folder in ("ca", "other-ca"):
        (root / folder).mkdir()
    certs.make_ca(root / "ca")
    certs.make_ca(root / "other-ca", name="someone-else")
    for name in ("gcs", "vision"):
        certs.make_leaf(root / "ground", name, ca_dir=root / "ca")
    certs.make_leaf(root / "rogue", "gcs", ca_dir=root / "other-ca")  # CN gcs, another CA's

    def signer(folder: str, name: str) -> StationSigner:
        return StationSigner.from_files(root / folder / f"{name}.pem", root / folder / f"{name}.key")

    gcs = signer("ground", "gcs")
    return Pki(gcs, signer("ground", "vision"), signer("rogue", "gcs"),
               FleetTrust.from_files(Path(root / "ca" / "ca.pem"), ["gcs"]),
               gcs.cert.not_valid_before_utc.timestamp() + 60.0, root / "ground")


def entry_of(request: w.WorldPut | w.WorldDelete, version: int = 1, origin: str = "uav_a") -> w.WorldEntry:
    """The entry a RAL makes of ``request``, after a trip over msgpack (as a peer's update carries it)."""
    body = request.body if isinstance(request, w.WorldPut) else None
    entry = w.WorldEntry(id=request.id, version=version, origin=origin, stamp=1.0, body=body,
                         deleted=body is None, **seal_of(request))
    return msgspec.msgpack.decode(msgspec.msgpack.encode(entry), type=w.WorldEntry)


def refused(entry: w.WorldEntry, pki: Pki) -> SignatureRefused:
    with pytest.raises(SignatureRefused) as info:
        world.entry_signer(entry, pki.trust, pki.now)
    return info.value


# ---------------------------------------------------------------- the decision, pure


def test_a_station_signed_zone_and_removal_are_admitted_however_they_arrive(pki: Pki) -> None:
    add = signed_request(w.WorldPut(id="mast", body=ZONE, author="gcs"), pki.gcs)
    remove = signed_request(w.WorldDelete(id="mast", author="gcs"), pki.gcs)
    fence = signed_request(w.WorldPut(id="field", body=w.Geofence(polygon=square(0.01))), pki.gcs)
    for request in (add, remove, fence):
        assert world.check_edit(w.edit_of_request(request), pki.trust, pki.now) == "gcs"
        # the same signature, carried by the entry at any version and origin (a peer's update or snapshot)
        assert world.entry_signer(entry_of(request, version=7, origin="uav_b"), pki.trust, pki.now) == "gcs"
    # the robots' own entries are not signed, and need not be
    target = w.WorldEntry(id="target.uav_b", version=3, origin="uav_b", stamp=1.0,
                          body=w.Target(lat=LAT, lon=LON, alt=30.0, seen_by="uav_b", seen_at=1.0))
    surveyed = w.WorldEntry(id="surveyed.uav_b.4", version=1, origin="uav_b", stamp=1.0,
                            body=w.Surveyed(polygon=square(), by="uav_b", at=1.0))
    assert world.entry_signer(target, pki.trust, pki.now) is None
    assert world.entry_signer(surveyed, pki.trust, pki.now) is None


def test_forged_zones_and_removals_are_refused_each_with_its_reason(pki: Pki) -> None:
    add = signed_request(w.WorldPut(id="mast", body=ZONE), pki.gcs)
    moved = msgspec.structs.replace(add, body=w.NoFlyZone(polygon=square(lat=LAT + 0.01), name="mast"))
    assert isinstance(refused(entry_of(moved), pki), BadSignature)
    renamed = msgspec.structs.replace(add, body=msgspec.structs.replace(ZONE, name="harmless"))
    assert isinstance(refused(entry_of(renamed), pki), BadSignature)
    as_fence = msgspec.structs.replace(add, body=w.Geofence(polygon=ZONE.polygon, name="mast"))
    assert isinstance(refused(entry_of(as_fence), pki), BadSignature)
    other = signed_request(w.WorldDelete(id="old_tower"), pki.gcs)  # a removal the station signed for another id
    why = refused(entry_of(msgspec.structs.replace(other, id="mast")), pki)
    assert isinstance(why, BadSignature) and "does not match the edit" in why.reason
    # the signature of the zone's addition does not remove it
    stolen = w.WorldDelete(id="mast", signer_cert=add.signer_cert, signature=add.signature)
    assert isinstance(refused(entry_of(stolen), pki), BadSignature)
    why = refused(entry_of(signed_request(w.WorldDelete(id="mast"), pki.module)), pki)
    assert isinstance(why, NotAGroundStation) and "'vision' is not a ground station" in why.reason
    assert isinstance(refused(entry_of(signed_request(w.WorldPut(id="fake", body=ZONE), pki.rogue)), pki),
                      UntrustedIssuer)
    assert isinstance(refused(entry_of(w.WorldDelete(id="mast")), pki), Unsigned)
    assert isinstance(refused(entry_of(w.WorldPut(id="fake", body=ZONE)), pki), Unsigned)
    # a robot's kind of entry under a zone's id is no robot entry: it would replace the zone
    target = w.Target(lat=LAT, lon=LON, alt=30.0, seen_by="uav_b", seen_at=1.0)
    assert isinstance(refused(entry_of(w.WorldPut(id="mast", body=target)), pki), Unsigned)
    # and no zone may take a robot's own id (any robot could overwrite it), signed or not
    why = refused(entry_of(signed_request(w.WorldPut(id="target.uav_b", body=ZONE), pki.gcs)), pki)
    assert isinstance(why, world.ReservedId) and "robot's own entry" in why.reason


# ---------------------------------------------------------------- world nodes on real Zenoh


def ask(session, robot: str, request: w.WorldRequest, within_s: float = 10.0) -> w.WorldReply:
    """The node's reply; asked again while no queryable answers (a node just made may not have its queryable at
    the router yet: a get then ends at once with no reply, as it did in a clean-clone run at load 30)."""
    end = time.monotonic() + within_s
    while True:
        for reply in session.get(w.world_request_key(robot), payload=msgspec.msgpack.encode(request),
                                 timeout=max(0.5, end - time.monotonic())):
            if reply.ok is not None:
                return msgspec.msgpack.decode(reply.ok.payload.to_bytes(), type=w.WorldReply)
        if time.monotonic() >= end:
            raise AssertionError(f"no reply from {robot}'s world node within {within_s:g} s")
        time.sleep(0.1)


def test_secured_nodes_apply_only_signed_edits_and_drop_forgeries_from_updates_and_snapshots(
        pki: Pki, nodes, router: int, clients, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="ral.world_bus")
    secured = {"trust": pki.trust, "trust_clock": time.time}  # requests are signed now, valid for minutes
    a, b = nodes("uav_a", **secured), nodes("uav_b", **secured)
    gcs = clients(router)
    # a station's request: unsigned refused, nothing applied; signed applied and spread with its signature
    reply = ask(gcs, "uav_a", w.WorldPut(id="mast", body=ZONE, author="gcs"))
    assert not reply.accepted and "zone 'mast' not applied: not signed by a ground station" in reply.reason
    assert a.get("mast") is None and a.snapshot().entries == []
    reply = ask(gcs, "uav_a", signed_request(w.WorldPut(id="mast", body=ZONE, author="gcs"), pki.gcs))
    assert reply.accepted and reply.entry is not None and reply.entry.signature
    wait_until(lambda: b.get("mast") == reply.entry, 10, "the signed zone at uav_b")
    zone = reply.entry

    # a taken robot (uav_x) publishes on its own key: removals of the zone (unsigned; with the signature of a
    # removal the station signed for another id), a fake zone, and its own target (the control)
    taken = clients(router)
    other = signed_request(w.WorldDelete(id="old_tower"), pki.gcs)
    forged = [
        w.WorldEntry(id="mast", version=5, origin="uav_x", stamp=2.0, deleted=True),
        w.WorldEntry(id="mast", version=6, origin="uav_x", stamp=2.0, deleted=True, signer_cert=other.signer_cert,
                     signature=other.signature),
        w.WorldEntry(id="fake", version=1, origin="uav_x", stamp=2.0, body=w.NoFlyZone(polygon=square(0.01))),
    ]
    seen = w.Target(lat=LAT, lon=LON, alt=30.0, seen_by="uav_x", seen_at=2.0)
    control = w.WorldEntry(id="target.uav_x", version=1, origin="uav_x", stamp=2.0, body=seen)
    taken.put(w.world_key("uav_x"), msgspec.msgpack.encode(w.WorldUpdate(robot="uav_x", entries=[*forged, control])))
    wait_until(lambda: a.get("target.uav_x") == control and b.get("target.uav_x") == control, 10,
               "the taken robot's own target (the control)")
    for node, station in ((a, 1), (b, 0)):  # uav_a also refused the station's unsigned request
        assert node.get("mast") == zone and node.get("fake") is None
        assert node.refusal(INSIDE) is not None and "no-fly zone 'mast'" in node.refusal(INSIDE)
        assert node.gate.refused == {"Unsigned": 2 + station, "BadSignature": 1}, node.gate.refused

    # the same forgeries in the taken robot's snapshot, asked for when its digest differs (anti-entropy)
    control2 = msgspec.structs.replace(control, version=2)
    snapshot = w.WorldSnapshot(robot="uav_x", digest="forged", entries=[*forged, control2])
    queryable = taken.declare_queryable(w.world_model_key("uav_x"), lambda q: q.reply(
        w.world_model_key("uav_x"), msgspec.msgpack.encode(snapshot)))
    try:
        taken.put(w.world_digest_key("uav_x"), msgspec.msgpack.encode(
            w.WorldDigest(robot="uav_x", digest="forged", entries=4)))
        wait_until(lambda: a.get("target.uav_x") == control2, 10, "the snapshot's control at uav_a")
    finally:
        queryable.undeclare()
    assert a.get("mast") == zone and a.get("fake") is None
    assert a.gate.refused["Unsigned"] >= 5 and a.gate.refused["BadSignature"] >= 2, a.gate.refused
    # never relayed: what uav_a serves holds none of them
    held = {(e.id, e.version) for e in a.snapshot().entries}
    assert held == {("mast", 1), ("target.uav_x", 2)}, held
    # logged once per distinct forgery, however many times it arrived (here at uav_a: update, then snapshot)
    fake_lines = [r for r in caplog.records if "entry 'fake' v1 from" in r.getMessage() and "refused" in
                  r.getMessage()]
    assert len(fake_lines) == 2, [r.getMessage() for r in fake_lines]  # one per node

    # a station-signed removal still applies, everywhere
    reply = ask(gcs, "uav_b", signed_request(w.WorldDelete(id="mast", author="gcs"), pki.gcs))
    assert reply.accepted and reply.entry is not None and reply.entry.deleted
    wait_until(lambda: a.get("mast") is None, 10, "the signed removal at uav_a")
    assert a.refusal(INSIDE) is None


def test_an_unsecured_node_merges_unsigned_zones_as_before(nodes, router: int, clients) -> None:
    a = nodes("uav_a")
    reply = ask(clients(router), "uav_a", w.WorldPut(id="mast", body=ZONE))
    assert reply.accepted and a.get("mast") is not None and a.gate.refused == {}


def test_gcs_world_signs_with_the_stations_certificate(pki: Pki, nodes, router: int, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture) -> None:
    from ral.gcs import cli

    a = nodes("uav_a", trust=pki.trust, trust_clock=time.time)
    ring = [[v.lon, v.lat] for v in square()]
    zone = tmp_path / "mast.geojson"
    zone.write_text(json.dumps({"type": "Polygon", "coordinates": [[*ring, ring[0]]]}))
    base = ["--connect", f"tcp/127.0.0.1:{router}", "--name", "gcs", "--timeout", "10"]
    identity = ["--cert", str(pki.ground / "gcs.pem"), "--key", str(pki.ground / "gcs.key")]
    assert cli.main([*base, "world", "add-nfz", "uav_a", str(zone)]) == 1
    assert "not signed by a ground station" in capsys.readouterr().out and a.get("mast") is None
    assert cli.main([*base, *identity, "world", "add-nfz", "uav_a", str(zone), "--label", "radio mast"]) == 0
    assert "added mast (version 1)" in capsys.readouterr().out
    entry = a.get("mast")
    assert entry is not None and world.entry_signer(entry, pki.trust, pki.now) == "gcs"
    assert cli.main([*base, "world", "show", "uav_a"]) == 0
    assert "no-fly   4 vertices (radio mast), signed by gcs" in capsys.readouterr().out
    assert cli.main([*base, "world", "remove", "uav_a", "mast"]) == 1
    assert "removal of 'mast' not applied" in capsys.readouterr().out and a.get("mast") == entry
    # a key that is not the certificate's: exit 2, nothing sent
    wrong = ["--cert", str(pki.ground / "gcs.pem"), "--key", str(pki.ground / "vision.key")]
    assert cli.main([*base, *wrong, "world", "remove", "uav_a", "mast"]) == 2
    assert "is not the key of" in capsys.readouterr().err and a.get("mast") == entry
    assert cli.main([*base, *identity, "world", "remove", "uav_a", "mast"]) == 0
    assert a.get("mast") is None


def test_a_captured_zone_request_replayed_never_undoes_a_newer_edit_nor_applies_after_its_expiry(
        pki: Pki, nodes, router: int, clients) -> None:
    """Whoever captured the station's signed request to add a zone sends it again after the station removed the
    zone (to put it back), and the removal again after the station re-added it: refused as ``Replayed`` by the robot
    asked, the model unchanged at both robots. A request replayed after its validity: ``Expired``."""
    clock = {"now": time.time()}
    secured = {"trust": pki.trust, "trust_clock": lambda: clock["now"]}
    a, b = nodes("uav_a", **secured), nodes("uav_b", **secured)
    gcs, attacker = clients(router), clients(router)
    at = clock["now"]
    add = signed_request(w.WorldPut(id="mast", body=ZONE, author="gcs"), pki.gcs)
    assert ask(gcs, "uav_a", add).accepted
    remove = signed_request(w.WorldDelete(id="mast", author="gcs"), pki.gcs)
    assert ask(gcs, "uav_a", remove).accepted
    wait_until(lambda: a.get("mast") is None and b.model.held("mast") is not None and b.get("mast") is None, 10,
               "the removal at both robots")
    reply = ask(attacker, "uav_b", add)  # the captured addition, to the other robot
    assert not reply.accepted and "edit of 'mast' not applied: signed at" in reply.reason, reply.reason
    assert a.get("mast") is None and b.get("mast") is None and b.gate.refused == {"Replayed": 1}
    readd = signed_request(w.WorldPut(id="mast", body=ZONE, author="gcs"), pki.gcs)
    assert ask(gcs, "uav_b", readd).accepted
    wait_until(lambda: a.get("mast") is not None, 10, "the zone re-added at uav_a")
    reply = ask(attacker, "uav_a", remove)  # the captured removal
    assert not reply.accepted and a.get("mast") is not None and a.gate.refused == {"Replayed": 1}
    assert b.get("mast") is not None
    # a fresh edit signed long ago, never used: expired once its validity (5 min) is past
    other = signed_request(w.WorldPut(id="tower", body=w.NoFlyZone(polygon=square(lat=LAT + 0.01))), pki.gcs)
    clock["now"] = at + 3600.0
    reply = ask(attacker, "uav_a", other)
    assert not reply.accepted and "valid until" in reply.reason and a.get("tower") is None
    assert a.gate.refused == {"Replayed": 1, "Expired": 1}
