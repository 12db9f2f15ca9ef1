"""The RAL's fleet-task gate (ral/fleet.py ``TaskGate``, ``FleetLink``) with an injected clock: on a secured robot
only a ground station's signed task is adopted, from a put or from a peer's fleet state; a forged one is dropped,
counted, logged once, and never bid on nor relayed in the robot's own fleet state. An unsecured robot adopts
every task as before. (Over real Zenoh: tests/system/test_secure_mesh.py.)"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import msgspec
import pytest

from bbcs.contracts.fleet import FleetState, FleetTarget, FleetTask
from bbcs.signing import FleetTrust, StationSigner
from cromat import certs
from ral.fleet import FleetLink, TaskGate
from ral.fleet_protocol import OwnState

TASK = FleetTask(id="t1", targets=[FleetTarget(id="a", lat=37.41, lon=-6.0, alt=30.0)])


@dataclass
class Keys:
    signer: StationSigner
    module: StationSigner
    trust: FleetTrust

    @property
    def now(self) -> float:
        """The robot's time: the wall clock (tasks are signed at it, valid for an hour; certificates for years)."""
        return time.time()


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Keys:
    root = tmp_path_factory.mktemp("fleet-signed")
    (root / "ca").mkdir()
    certs.make_ca(root / "ca")
    for name in ("gcs", "vision"):
        certs.make_leaf(root / "ground", name, ca_dir=root / "ca")
    signer = StationSigner.from_files(root / "ground" / "gcs.pem", root / "ground" / "gcs.key")
    module = StationSigner.from_files(root / "ground" / "vision.pem", root / "ground" / "vision.key")
    return Keys(signer, module, FleetTrust.from_files(Path(root / "ca" / "ca.pem"), ["gcs"]))


class _Payload:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


class _Sample:
    """What FleetLink's callbacks read of a Zenoh sample: its payload."""

    def __init__(self, value: object) -> None:
        self.payload = _Payload(msgspec.msgpack.encode(value))


def link(trust: FleetTrust | None, now: float) -> FleetLink:
    own = OwnState(lat=37.41, lon=-6.0, alt=30.0, speed=5.0, can_do=frozenset({"visit"}))
    return FleetLink("uav1", "uav", lambda: own, lambda job: None, clock=lambda: now, trust=trust)


def peer_state(*tasks: FleetTask) -> FleetState:
    return FleetState(robot="uav2", kind="uav", stamp=0.0, tasks=list(tasks))


def test_a_secured_robot_adopts_a_signed_task_from_a_put_and_from_a_peers_state(pki: Keys) -> None:
    for deliver in ("_on_task", "_on_state"):
        fleet = link(pki.trust, pki.now)
        task = pki.signer.sign(TASK)
        getattr(fleet, deliver)(_Sample(task if deliver == "_on_task" else peer_state(task)))
        assert list(fleet.node.runs) == ["t1"]
        # adopted: it bids on it and relays it in its own fleet state (signature included)
        fleet.node.tick(fleet.own(), pki.now)
        state = fleet.node.state(pki.now)
        assert state.tasks == [task] and [b.task for b in state.bids] == ["t1"]


def test_forged_tasks_in_a_peers_state_are_never_adopted_bid_on_or_relayed(pki: Keys, caplog) -> None:
    fleet = link(pki.trust, pki.now)
    good = pki.signer.sign(TASK)
    moved = msgspec.structs.replace(good, id="t2", targets=[msgspec.structs.replace(good.targets[0], lat=37.5)])
    unsigned = FleetTask(id="t3", targets=TASK.targets)
    by_module = pki.module.sign(msgspec.structs.replace(TASK, id="t4"))
    caplog.set_level(logging.INFO, logger="ral.fleet")
    for _ in range(3):  # the peer republishes its state every period
        fleet._on_state(_Sample(peer_state(moved, unsigned, by_module, good)))
    assert list(fleet.node.runs) == ["t1"]
    fleet.node.tick(fleet.own(), pki.now)
    state = fleet.node.state(pki.now)
    assert [x.id for x in state.tasks] == ["t1"] and {b.task for b in state.bids} == {"t1"}
    assert fleet.gate.refused == {"BadSignature": 3, "Unsigned": 3, "NotAGroundStation": 3}
    refusals = [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
    assert len(refusals) == 3, refusals  # once per forged task, with the reason
    assert any("t2 from uav2's fleet state refused: signature by 'gcs' does not match" in m for m in refusals)
    assert any("t3 from uav2's fleet state refused: not signed" in m for m in refusals)
    assert any("t4 from uav2's fleet state refused: signer 'vision' is not a ground station" in m for m in refusals)


def test_a_changed_copy_of_an_adopted_task_does_not_pass_as_the_adopted_one(pki: Keys) -> None:
    fleet = link(pki.trust, pki.now)
    good = pki.signer.sign(TASK)
    fleet._on_task(_Sample(good))
    moved = msgspec.structs.replace(good, targets=[msgspec.structs.replace(good.targets[0], lat=37.5)])
    fleet._on_state(_Sample(peer_state(moved)))
    assert fleet.node.runs["t1"].task == good
    assert fleet.gate.refused == {"BadSignature": 1}


def test_an_expired_signer_is_refused_at_the_robots_time(pki: Keys) -> None:
    late = pki.signer.cert.not_valid_after_utc.timestamp() + 1.0
    fleet = link(pki.trust, late)
    fleet._on_task(_Sample(pki.signer.sign(TASK)))
    assert fleet.node.runs == {} and fleet.gate.refused == {"NotValidNow": 1}


def test_an_unsecured_robot_adopts_any_task_as_before(pki: Keys) -> None:
    fleet = link(None, 0.0)
    fleet._on_state(_Sample(peer_state(FleetTask(id="t3", targets=TASK.targets))))
    assert list(fleet.node.runs) == ["t3"] and fleet.gate.refused == {}


def test_the_gate_remembers_a_bounded_number_of_verdicts(pki: Keys) -> None:
    gate = TaskGate(pki.trust, lambda: pki.now, remember=2)
    tasks = [FleetTask(id=f"u{i}", targets=TASK.targets) for i in range(5)]
    for task in tasks:
        assert not gate.admit(task, "test")
    assert len(gate._seen) == 2 and gate.refused == {"Unsigned": 5}
