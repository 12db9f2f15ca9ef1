"""``Gcs.watch`` through a real router: a robot state that does not decode is dropped and counted (it used to vanish
without a trace), and the states around it still reach the callback in order."""

from __future__ import annotations

import time

from bbcs.contracts import gri
from bbcs.session import local_client, open_session
from bbcs.testing import wait_until
from ral.gcs.api import Gcs

ROBOT = "uav1"


def test_an_undecodable_state_is_dropped_and_counted(router: int) -> None:
    robot = open_session(local_client(router))
    station = Gcs(local_client(router), name="station")
    try:
        got: list[float] = []
        station.watch(ROBOT, lambda s: got.append(s.stamp))
        pub = robot.declare_publisher(gri.state_key(ROBOT))
        deadline = time.monotonic() + 20
        while not got:  # the subscription is up end to end once one state is through
            assert time.monotonic() < deadline, "the station never heard the robot"
            pub.put(gri.encode(gri.GriState(robot=ROBOT, stamp=1.0)))
            time.sleep(0.05)
        pub.put(b"\x93not a state")
        pub.put(gri.encode(gri.GriState(robot=ROBOT, stamp=2.0)))
        wait_until(lambda: 2.0 in got, 10, "the state after the corrupt one")
        assert station.refused_states == 1
        assert set(got) == {1.0, 2.0} and got[-1] == 2.0
        pub.undeclare()
    finally:
        station.close()
        robot.close()
