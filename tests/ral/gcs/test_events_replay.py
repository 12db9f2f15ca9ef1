"""A ground station misses no GRI event while its link to the robot is cut: the events come when the link is back.

Real routers: the robot's, and a ground router that reaches it through a TCP relay on 127.0.0.1 which the test cuts
(every connection closed, new ones refused) and heals (the ground router reconnects by itself). The robot side
publishes with the RAL's own event publisher (``ral.gri_service.events_publisher``); the station listens with
``Gcs.events``. The control: the same cut with a plain reliable publisher loses the events.
"""

from __future__ import annotations

import time

import pytest

from bbcs.contracts import gri
from bbcs.session import local_client, open_session
from bbcs.slots import Direction, Kind, Publisher, Safety, SlotSpec
from bbcs.testing import CutRelay, Processes, start_router, wait_until
from ral.gcs.api import Gcs
from ral.gri_service import events_publisher

ROBOT = "uav1"


@pytest.fixture
def ground():
    """(robot-side session, a station on the ground router, the relay between the routers)."""
    procs = Processes()
    try:
        robot_port = start_router(procs)
        relay = CutRelay.tcp(robot_port)
        ground_port = start_router(procs, connect=(f"tcp/127.0.0.1:{relay.port}",))
        robot = open_session(local_client(robot_port))
        station = Gcs(local_client(ground_port), name="station", timeout_s=10.0)
        try:
            yield robot, station, relay
        finally:
            station.close()
            robot.close()
            relay.close()
    finally:
        procs.stop_all()


def event(n: int) -> gri.GriEvent:
    return gri.GriEvent(robot=ROBOT, stamp=float(n), kind="task_accepted", task_id=n, task_type="goto")


def heard(pub: Publisher[gri.GriEvent], got: list[int], n: int) -> None:
    """Publish event ``n`` every half second until the station has it: the routers' link and the station's
    subscription are up end to end."""
    deadline = time.monotonic() + 30
    while n not in got:
        assert time.monotonic() < deadline, "the station never heard the robot"
        pub.publish(event(n))
        end = time.monotonic() + 0.5
        while n not in got and time.monotonic() < end:
            time.sleep(0.01)


def through_a_cut(pub: Publisher[gri.GriEvent], station: Gcs, relay: CutRelay, *, resend_7: bool = False) -> list[int]:
    """Events 1–3 before the cut, 4–6 during it, 7 the moment the routers reconnect (sent once; or until the
    station has it, ``resend_7``); the task ids (above 0) the station got once 7 arrived."""
    got: list[int] = []
    station.events(ROBOT, lambda e: got.append(e.task_id))
    heard(pub, got, 0)
    for n in (1, 2, 3):
        pub.publish(event(n))
    wait_until(lambda: [i for i in got if i] == [1, 2, 3], 10, "the events before the cut")
    relay.cut()
    for n in (4, 5, 6):  # every connection between the routers is closed: these cannot get through
        pub.publish(event(n))
    relay.heal()
    wait_until(lambda: relay.accepted >= 2, 30, "the ground router reconnected through the relay")
    if resend_7:
        heard(pub, got, 7)
    else:
        pub.publish(event(7))  # likely before the routes are back: it too must come from the replay
        wait_until(lambda: 7 in got, 30, "the event published as the link came back")
    return [i for i in got if i]


def test_events_published_during_a_cut_reach_the_station_when_it_heals(ground):
    robot, station, relay = ground
    pub = events_publisher(robot, ROBOT)
    try:
        got = through_a_cut(pub, station, relay)
    finally:
        pub.close()
    assert got == [1, 2, 3, 4, 5, 6, 7], "every event once, in order, those of the cut included"


def test_a_station_that_subscribes_late_gets_no_earlier_event(ground):
    """Replay fills a gap in what a station was following; it is not a history of what came before it."""
    robot, station, _relay = ground
    pub = events_publisher(robot, ROBOT)
    early: list[int] = []
    late: list[int] = []
    try:
        station.events(ROBOT, lambda e: early.append(e.task_id))
        heard(pub, early, 1)
        station.events(ROBOT, lambda e: late.append(e.task_id))
        pub.publish(event(2))
        wait_until(lambda: 2 in late and 2 in early, 30, "event 2 at both subscriptions")
    finally:
        pub.close()
    assert late == [2]


def test_control_a_plain_reliable_publisher_loses_the_events_of_the_cut(ground):
    robot, station, relay = ground
    spec = SlotSpec("events", gri.GriEvent, Direction.OUT, Kind.STREAM, Safety.SAFE)
    pub = Publisher(robot, gri.events_key(ROBOT), spec)
    try:
        got = through_a_cut(pub, station, relay, resend_7=True)
    finally:
        pub.close()
    assert 7 in got and not {4, 5, 6} & set(got), got
