"""A station that links with a robot hears the robot's answer to its link, however late it calls ``events()``.

The RAL publishes ``link_up`` the moment it sees a station's token and heartbeat, which can be before the station's
program has subscribed to the events. The robot side here does the same on a real router: it publishes as soon as
the station's liveliness token appears. The control: a station that does not link, subscribing just as late,
gets nothing from before its subscription.
"""

from __future__ import annotations

import threading
import time

import pytest
import zenoh

from bbcs.contracts import gri
from bbcs.session import local_client, open_session
from bbcs.testing import Processes, start_router, wait_until
from ral.gcs.api import Gcs
from ral.gri_service import events_publisher

ROBOT = "uav1"


def event(n: int, kind: str = "task_accepted") -> gri.GriEvent:
    return gri.GriEvent(robot=ROBOT, stamp=float(n), kind=kind, task_id=n)  # type: ignore[arg-type]


@pytest.fixture
def router_port():
    procs = Processes()
    try:
        yield start_router(procs)
    finally:
        procs.stop_all()


def test_a_linked_station_gets_the_events_that_answered_its_link(router_port: int) -> None:
    robot = open_session(local_client(router_port))
    pub = events_publisher(robot, ROBOT)
    answered = threading.Event()

    def on_token(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT and not answered.is_set():
            pub.publish(event(1, "link_up"))
            answered.set()

    # with history, as the RAL watches the stations: a token declared before this subscription reached the router
    # is still seen (without it, a clean-clone run at load 30 never saw the station's token)
    watcher = robot.liveliness().declare_subscriber(gri.gcs_alive_key("station"), on_token, history=True)
    other = station = None
    try:
        other = Gcs(local_client(router_port), name="other", timeout_s=10.0)
        station = Gcs(local_client(router_port), name="station", link=[ROBOT], timeout_s=10.0)
        assert answered.wait(10), "the robot side never saw the station's token"
        first: list[int] = []
        late_other: list[int] = []
        station.events(ROBOT, lambda e: first.append(e.task_id))  # after the robot answered
        wait_until(lambda: first == [1], 10, "the link's answer at the linked station")
        # the control subscribes once the answer has passed the router (the linked station heard it): a put
        # returns before its bytes leave the robot's session, and on a loaded machine they reached the router
        # after the other station's subscription had (a clean-clone run: late_other == [1, 2])
        other.events(ROBOT, lambda e: late_other.append(e.task_id))
        # the other station's subscription reaches the router some time after its call: events 2, 3, … until it
        # hears one (every one of them reaches the linked station)
        n = 2
        deadline = time.monotonic() + 30
        while not late_other:
            assert time.monotonic() < deadline, "the other station never heard the robot"
            pub.publish(event(n))
            n += 1
            end = time.monotonic() + 0.5
            while not late_other and time.monotonic() < end:
                time.sleep(0.01)
        sent = list(range(2, n))
        wait_until(lambda: first == [1, *sent], 10, "every event at the linked station")
        second: list[int] = []
        with station.events(ROBOT, lambda e: second.append(e.task_id)):
            assert second == [1, *sent], "a callback added later gets what came since the link began, in order"
        pub.publish(event(n))
        wait_until(lambda: n in first, 10, f"event {n}")
    finally:
        for gcs in (station, other):
            if gcs is not None:
                gcs.close()
        watcher.undeclare()
        pub.close()
        robot.close()
    assert first == [1, *sent, n], "each event once, in order"
    assert second == [1, *sent], "a closed subscription gets nothing more"
    assert 1 not in late_other, "control: without the link, nothing from before the subscription"
