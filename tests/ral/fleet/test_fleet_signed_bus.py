"""Replay and revocation over real Zenoh: a real router, the RAL's own FleetLink (its gate, its protocol) on client
sessions of it, flying a point robot, ground stations and an attacker on sessions of the same router.

- A captured signed task, replayed after the robot finished it and restarted (its memory of the task gone), once
  the task's validity is past: never adopted nor flown (the robot's log and counter say ``Expired``), while a task
  the station signs afterwards is adopted and flown (the control).
- A station revoked with ``cromat certs --revoke`` while the robot runs: its signed task is refused (``Revoked``)
  and never flown, the other station's task is adopted and flown.
"""

from __future__ import annotations

import dataclasses
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts.fleet import FleetTarget, FleetTask
from bbcs.signing import CLOCK_TOLERANCE_S, FleetTrust
from bbcs.testing import wait_until
from cromat import certs
from ral.fleet import FleetLink
from ral.fleet_protocol import Execute, FleetConfig, OwnState

LAT, LON, ALT = 37.41, -6.0, 30.0

sys.path.insert(0, str(Path(__file__).resolve().parent))
from station_pki import Pki  # noqa: E402


def task(task_id: str, north_m: float) -> FleetTask:
    return FleetTask(id=task_id, targets=[FleetTarget(id="a", lat=LAT + north_m / 111_000.0, lon=LON, alt=ALT)])


@pytest.fixture(scope="module")
def issued(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return Pki(tmp_path_factory.mktemp("pki"))


@pytest.fixture
def pki(issued: Pki, tmp_path: Path) -> Pki:
    """A fresh copy of the file's one issued PKI for each test (a test may revoke a station in it)."""
    return Pki.copy_of(issued, tmp_path)


class Robot:
    """One RAL's fleet side on its own session: FleetLink ticked every 20 ms by a thread, a point robot that is at
    whatever it was given to fly by the next tick; ``flown``: every share it was given."""

    def __init__(self, session, name: str, trust: FleetTrust, clock: Callable[[], float]) -> None:  # noqa: ANN001
        self.flown: list[Execute] = []
        self.own = OwnState(lat=LAT, lon=LON, alt=ALT, speed=5.0, can_do=frozenset({"visit"}))
        self.token = session.liveliness().declare_token(keys.alive_key(name, "ral"))
        self.link = FleetLink(name, "uav", lambda: self.own, self._fly, FleetConfig(bid_window_s=0.5), clock=clock,
                              trust=trust)
        self.link.start(session)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _fly(self, job: Execute) -> None:
        self.flown.append(job)
        last = job.targets[-1]
        self.own = dataclasses.replace(self.own, lat=last.lat, lon=last.lon, alt=last.alt)

    def _run(self) -> None:
        while not self._stop.wait(0.02):
            self.link.tick()

    def finished(self, task_id: str) -> bool:
        run = self.link.node.runs.get(task_id)
        return run is not None and run.complete

    def flew(self, task_id: str) -> bool:
        return any(j.task.id == task_id for j in self.flown)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.link.stop()
        self.token.undeclare()


@pytest.fixture
def robots(router: int, clients) -> Iterator[Callable[..., Robot]]:  # noqa: ANN001
    made: list[Robot] = []

    def make(name: str, trust: FleetTrust, clock: Callable[[], float]) -> Robot:
        robot = Robot(clients(router), name, trust, clock)
        made.append(robot)
        return robot

    yield make
    for robot in reversed(made):
        if not robot._stop.is_set():
            robot.stop()


def put(session, item: FleetTask) -> None:  # noqa: ANN001
    """Put ``item`` once ``session`` knows a robot's task subscriber (a put that reaches the router before the
    subscription does is delivered to no one)."""
    publisher = session.declare_publisher(keys.fleet_task_key(item.id))
    try:
        wait_until(lambda: publisher.matching_status.matching, 20, f"a subscriber of {item.id} seen by the sender")
        publisher.put(msgspec.msgpack.encode(item))
    finally:
        publisher.undeclare()


def test_a_captured_task_replayed_after_the_robot_finished_it_and_restarted_is_not_flown(
        pki: Pki, robots, router: int, clients) -> None:  # noqa: ANN001
    gcs = pki.signer("gcs1")
    clock = {"offset": 0.0}

    def now() -> float:
        return time.time() + clock["offset"]

    station, attacker = clients(router), clients(router)
    robot = robots("uav1", pki.trust(), now)
    captured = gcs.sign(task("survey1", 100.0), lifetime_s=60.0)
    put(station, captured)  # the attacker records these bytes
    wait_until(lambda: robot.finished("survey1"), 20, "uav1 to fly and finish survey1")
    assert robot.flew("survey1")

    robot.stop()  # the robot restarts: a new RAL, no memory of survey1; its clock is now past survey1's validity
    clock["offset"] = captured.valid_until + CLOCK_TOLERANCE_S + 1.0 - now()
    restarted = robots("uav1", pki.trust(), now)
    control = gcs.sign(task("survey2", 200.0), now=now())
    put(station, control)
    wait_until(lambda: restarted.finished("survey2"), 20, "the restarted uav1 to fly the station's new task")
    # The attacker replays the captured bytes until the robot has them: its session may still count the stopped
    # robot's subscriber as a match, and a replay that never reached the restarted robot would prove nothing.
    replayed_at = 0.0

    def replay_refused() -> bool:
        nonlocal replayed_at
        if restarted.link.gate.refused["Expired"] >= 1:
            return True
        if time.monotonic() - replayed_at > 0.5:
            put(attacker, captured)
            replayed_at = time.monotonic()
        return False

    wait_until(replay_refused, 10, "the replayed survey1 refused")
    assert "survey1" not in restarted.link.node.runs and not restarted.flew("survey1")
    assert set(restarted.link.gate.refused) == {"Expired"}


def test_a_revoked_stations_task_is_refused_the_other_stations_is_flown(
        pki: Pki, robots, router: int, clients) -> None:  # noqa: ANN001
    robot = robots("uav1", pki.trust(), time.time)
    station1, station2 = clients(router), clients(router)
    put(station1, pki.signer("gcs1").sign(task("before", 50.0)))  # before the revocation: adopted
    wait_until(lambda: robot.finished("before"), 20, "gcs1's task before its revocation")
    assert certs.main([str(pki.robot), "--revoke", "gcs1"]) == 0  # the robot reads the new list while it runs
    put(station1, pki.signer("gcs1").sign(task("stolen", 150.0)))
    put(station2, pki.signer("gcs2").sign(task("genuine", 250.0)))
    wait_until(lambda: robot.finished("genuine"), 20, "gcs2's task flown")
    wait_until(lambda: robot.link.gate.refused["Revoked"] >= 1, 10, "gcs1's task refused")
    assert "stolen" not in robot.link.node.runs and not robot.flew("stolen")
    assert robot.flew("genuine") and set(robot.link.gate.refused) == {"Revoked"}


def test_the_station_chooses_the_lifetime_of_what_it_posts(pki: Pki, router: int, clients) -> None:  # noqa: ANN001
    from ral.fleet_gcs import FleetView

    view = FleetView(clients(router))
    try:
        unsigned = task("t9", 10.0)
        posted = view.post(unsigned, pki.signer("gcs1"), lifetime_s=120.0)
        assert posted.valid_until - posted.signed_at == 120.0 and posted.targets == unsigned.targets
    finally:
        view.close()
