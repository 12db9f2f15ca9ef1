"""Replay and revocation at the RAL's gates (ral/signed.py, ral/fleet.py ``TaskGate``/``FleetLink``, ral/world.py's
ordering), by attack, with an injected clock and real certificates: a finished task replayed to a restarted robot
after its expiry; an older signature of a task id presented after the station re-posted it; a station revoked
while the robot runs; an older zone edit replayed over a newer one, with any version a RAL gives it.
(Over real Zenoh: test_fleet_signed_bus.py, and the world requests in test_world_signed.py.)"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import msgspec
import pytest

from bbcs.contracts import tasks as t
from bbcs.contracts import world as w
from bbcs.contracts.fleet import FleetState, FleetTarget, FleetTask
from bbcs.contracts.signed import seal_of
from bbcs.signing import CLOCK_TOLERANCE_S, FleetTrust
from cromat import certs
from ral import world
from ral.fleet import FleetLink, TaskGate
from ral.fleet_protocol import Execute, OwnState

TARGET = FleetTarget(id="a", lat=37.41, lon=-6.0, alt=30.0)
TASK = FleetTask(id="t1", targets=[TARGET])

sys.path.insert(0, str(Path(__file__).resolve().parent))
from station_pki import Pki  # noqa: E402


@pytest.fixture(scope="module")
def issued(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return Pki(tmp_path_factory.mktemp("pki"))


@pytest.fixture
def pki(issued: Pki, tmp_path: Path) -> Pki:
    """A fresh copy of the file's one issued PKI for each test (a test may revoke a station in it)."""
    return Pki.copy_of(issued, tmp_path)


class Clock:
    def __init__(self, now: float) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


class _Sample:
    """What FleetLink's callbacks read of a Zenoh sample: its payload."""

    def __init__(self, value: object) -> None:
        data = msgspec.msgpack.encode(value)
        self.payload = type("P", (), {"to_bytes": lambda _self: data})()


class Robot:
    """A RAL's FleetLink on a point robot 100 m from the target: whatever it is given to fly it has flown by the
    next tick."""

    def __init__(self, trust: FleetTrust, clock: Clock) -> None:
        self.flown: list[Execute] = []
        self.own = OwnState(lat=TARGET.lat - 0.001, lon=TARGET.lon, alt=TARGET.alt, speed=5.0,
                            can_do=frozenset({"visit"}))
        self.link = FleetLink("uav1", "uav", lambda: self.own, self.fly, clock=clock, trust=trust)
        self.clock = clock

    def fly(self, job: Execute) -> None:
        self.flown.append(job)
        last = job.targets[-1]
        self.own = OwnState(lat=last.lat, lon=last.lon, alt=last.alt, speed=5.0, can_do=frozenset({"visit"}))

    def put(self, task: FleetTask) -> None:
        self.link._on_task(_Sample(task))

    def tick(self) -> None:
        for _ in range(3):
            self.link.tick()


def peer_state(*tasks: FleetTask) -> FleetState:
    return FleetState(robot="uav2", kind="uav", stamp=0.0, tasks=list(tasks))


# ---------------------------------------------------------------- fleet tasks


def test_a_finished_task_replayed_to_a_restarted_robot_is_adopted_only_within_its_validity(pki: Pki) -> None:
    """A restart loses the robot's memory of the tasks it finished: what bounds a replay then is the task's
    validity. Within it the replay is adopted again (the documented limit); after it, refused."""
    gcs = pki.signer("gcs1")
    clock = Clock(gcs.cert.not_valid_before_utc.timestamp() + 60.0)
    captured = gcs.sign(TASK, now=clock.now, lifetime_s=600.0)
    robot = Robot(pki.trust(), clock)
    robot.put(captured)
    robot.tick()
    assert robot.link.node.runs["t1"].complete and [j.task.id for j in robot.flown] == ["t1"]
    robot.put(captured)  # the same robot, alive: it never starts a task id twice
    robot.tick()
    assert len(robot.flown) == 1

    clock.now += 300.0  # restarted within the validity: adopted again (its memory is gone)
    restarted = Robot(pki.trust(), clock)
    restarted.put(captured)
    assert "t1" in restarted.link.node.runs

    clock.now = captured.valid_until + CLOCK_TOLERANCE_S + 1.0  # restarted after it: refused
    late = Robot(pki.trust(), clock)
    late.put(captured)
    late.link._on_state(_Sample(peer_state(captured)))  # also when a peer that still holds it relays it
    late.tick()
    assert late.link.node.runs == {} and late.flown == []
    assert late.link.gate.refused == {"Expired": 2}


def test_an_older_signature_of_a_task_id_is_replayed_a_re_post_is_taken(pki: Pki,
                                                                        caplog: pytest.LogCaptureFixture) -> None:
    gcs = pki.signer("gcs1")
    clock = Clock(gcs.cert.not_valid_before_utc.timestamp() + 60.0)
    first = gcs.sign(TASK, now=clock.now, lifetime_s=600.0)
    robot = Robot(pki.trust(), clock)
    robot.put(first)
    robot.tick()
    clock.now += 500.0  # the station re-posts the same task before it expires: a newer signature, same work
    again = gcs.sign(TASK, now=clock.now, lifetime_s=600.0)
    robot.link._on_state(_Sample(peer_state(again)))
    run = robot.link.node.runs["t1"]
    assert run.task == again and run.complete and len(robot.flown) == 1  # the run goes on, not flown twice
    assert robot.link.node.state(clock.now).tasks == [again]  # the fresher signature is what it relays
    # the first signature again (a peer that lags, or whoever captured it), three times: refused, logged once
    caplog.set_level(logging.INFO, logger="ral.fleet")
    for _ in range(3):
        robot.put(first)
    assert robot.link.gate.refused == {"Replayed": 3} and robot.link.node.runs["t1"].task == again
    lines = [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
    assert len(lines) == 1 and "fleet task t1 from a ground station's put refused: signed at" in lines[0]
    # other work under the same id, newer: not flown (a task id is flown once), the held copy stays
    moved = gcs.sign(msgspec.structs.replace(TASK, targets=[msgspec.structs.replace(TARGET, lat=37.5)]),
                     now=clock.now + 1.0)
    robot.put(moved)
    robot.tick()
    assert robot.link.node.runs["t1"].task == again and len(robot.flown) == 1
    assert any("re-signed with other targets" in r.getMessage() for r in caplog.records)


def test_the_replay_memory_lasts_until_the_tasks_expiry(pki: Pki) -> None:
    gcs = pki.signer("gcs1")
    clock = Clock(gcs.cert.not_valid_before_utc.timestamp() + 60.0)
    gate = TaskGate(pki.trust(), clock)
    old, new = (gcs.sign(TASK, now=clock.now + d, lifetime_s=100.0) for d in (0.0, 1.0))
    assert gate.admit(new, "test") and len(gate.replay) == 1  # type: ignore[arg-type]
    assert not gate.admit(old, "test") and gate.refused == {"Replayed": 1}
    clock.now = new.valid_until + CLOCK_TOLERANCE_S + 1.0
    assert not gate.admit(old, "test") and gate.refused["Expired"] == 1
    assert len(gate.replay) == 0  # type: ignore[arg-type]


# ---------------------------------------------------------------- revocation


def test_a_station_revoked_while_the_robot_runs_signs_nothing_it_adopts(pki: Pki,
                                                                       caplog: pytest.LogCaptureFixture) -> None:
    gcs1, gcs2 = pki.signer("gcs1"), pki.signer("gcs2")
    clock = Clock(gcs1.cert.not_valid_before_utc.timestamp() + 60.0)
    gate = TaskGate(pki.trust(), clock)
    before = gcs1.sign(TASK, now=clock.now)
    assert gate.admit(before, "test")  # no list yet
    assert certs.main([str(pki.robot), "--revoke", "gcs1"]) == 0
    caplog.set_level(logging.INFO, logger="ral.fleet")
    # read again at the next arrival: the task admitted before (its verdict remembered) and a new one, refused
    assert not gate.admit(before, "test")
    assert not gate.admit(gcs1.sign(msgspec.structs.replace(TASK, id="t2"), now=clock.now), "test")
    assert gate.admit(gcs2.sign(msgspec.structs.replace(TASK, id="t3"), now=clock.now), "test")
    assert gate.refused == {"Revoked": 2}
    assert any("revoked by the fleet CA" in r.getMessage() for r in caplog.records)
    # a list someone else signed (another CA's, revoking nothing) does not lift the revocation
    other = pki.root / "other"
    (pki.root / "other-ca").mkdir()
    certs.make_ca(pki.root / "other-ca", name="someone-else")
    certs.make_leaf(other, "x", ca_dir=pki.root / "other-ca")
    certs.revoke(pki.root / "other-ca", other / "x.pem", [])
    (pki.robot / "crl.pem").write_bytes((pki.root / "other-ca" / "crl.pem").read_bytes())
    assert not gate.admit(before, "test") and gate.refused == {"Revoked": 3}
    assert any("not reloaded, the previous one stays in force" in r.getMessage() for r in caplog.records)


# ---------------------------------------------------------------- zone edits


def entry(edit: w.StationEdit, version: int, origin: str) -> w.WorldEntry:
    return w.WorldEntry(id=edit.id, version=version, origin=origin, stamp=1.0, deleted=edit.remove,
                        body=edit.body, **seal_of(edit))


def test_an_older_signed_zone_edit_never_undoes_a_newer_one_whatever_its_version(pki: Pki) -> None:
    gcs = pki.signer("gcs1")
    at = gcs.cert.not_valid_before_utc.timestamp() + 60.0
    zone = w.NoFlyZone(polygon=[t.Vertex(lat=37.41, lon=-6.0), t.Vertex(lat=37.42, lon=-6.0),
                                t.Vertex(lat=37.42, lon=-6.01)])
    put = gcs.sign(w.StationEdit(id="mast", remove=False, body=zone), now=at)
    removal = gcs.sign(w.StationEdit(id="mast", remove=True), now=at + 10.0)
    for order in ((entry(put, 1, "uav_a"), entry(removal, 2, "uav_a"), entry(put, 9, "uav_x")),
                  (entry(put, 9, "uav_x"), entry(removal, 2, "uav_a")),
                  (entry(removal, 2, "uav_a"), entry(put, 1, "uav_a"))):
        model = world.WorldModel()
        model.merge_all(order)
        assert model.get("mast") is None, order  # the removal, signed later, holds in any order
    # the robots' own entries still rank by version (unsigned)
    model = world.WorldModel()
    seen = w.Target(lat=37.41, lon=-6.0, alt=30.0, seen_by="uav_b", seen_at=1.0)
    model.merge(w.WorldEntry(id="target.uav_b", version=1, origin="uav_b", stamp=1.0, body=seen))
    model.merge(entry(gcs.sign(w.StationEdit(id="target.uav_b", remove=True), now=at), 2, "uav_a"))
    assert model.get("target.uav_b") is None
    model.merge(w.WorldEntry(id="target.uav_b", version=3, origin="uav_b", stamp=2.0, body=seen))
    assert model.get("target.uav_b") is not None


def test_a_revoked_stations_zone_edit_is_refused_as_a_request_and_as_an_entry(pki: Pki) -> None:
    """The world node's gate (ral/world_bus.py: ``check_edit``) reads the same revocation list as the fleet's."""
    from ral.signed import SignatureGate

    gcs1, gcs2 = pki.signer("gcs1"), pki.signer("gcs2")
    clock = Clock(gcs1.cert.not_valid_before_utc.timestamp() + 60.0)
    gate = SignatureGate(pki.trust(), clock, "world edit", check=world.check_edit)  # type: ignore[arg-type]
    assert certs.main([str(pki.robot), "--revoke", "gcs1"]) == 0
    zone = w.NoFlyZone(polygon=[t.Vertex(lat=37.41, lon=-6.0), t.Vertex(lat=37.42, lon=-6.0),
                                t.Vertex(lat=37.42, lon=-6.01)])
    stolen = gcs1.sign(w.StationEdit(id="mast", remove=True), now=clock.now)
    why = gate.refusal(stolen, "a ground station's request", "removal of 'mast'")
    assert why is not None and "revoked by the fleet CA" in why
    assert not gate.admit(stolen, "uav2's update", "removal of 'mast' v3", expiry=False)
    assert gate.admit(gcs2.sign(w.StationEdit(id="mast", remove=False, body=zone), now=clock.now), "x", "zone")
    assert gate.refused == {"Revoked": 2}
