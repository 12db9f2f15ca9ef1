"""Issue 11, "every path flies at a known speed": the task's speed reaches the DSP before the first waypoint of
its path, also when the speed is slow on its way.

The speed and the path are two inputs of the path follower (VELOCIDAD, DATOS). The RAL publishes the speed,
waits for the path follower's ``speed_ack`` (sent once its SET_SPEED is on the DSP command stream), and only then
publishes the path (docs/gcs.md, "Speed before path"). Here the speed is delayed on its way: the manifest's slot
13 (VELOCIDAD) is a relay that this test feeds from the RAL's ``ral/speed`` half a second late. Without the
answer the path would reach the DSP first; the simulator's record shows SET_SPEED with the task's speed before
the path's first ADD_WAYPOINT, and the aircraft flies the path to completion.
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import pytest
import zenoh

from bbcs import keys
from bbcs.contracts import tasks as t
from bbcs.testing import wait_until

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_command_path import Factory, ended, make_robot, names  # noqa: E402,F401,F811
from test_gcs_mission import ROBOT, grid_path  # noqa: E402

DELAY_S = 0.5
SPEED = 3.0
"""Not the cruise speed (5), so its SET_SPEED is told apart from any earlier one."""
RELAY = "speed_relay"


def relay_speed_slot(text: str) -> str:
    """Slot 13 (the path follower's VELOCIDAD) read from the relay's key instead of the RAL's."""
    old = 'number = 13\nmodule = "ral"\nslot = "speed"'
    assert old in text, "slot 13 of uav1_sim.toml changed"
    return text.replace(old, f'number = 13\nmodule = "{RELAY}"\nslot = "speed"')


def test_the_speed_reaches_the_dsp_before_the_first_waypoint_even_when_delayed(make_robot: Factory) -> None:  # noqa: F811
    robot = make_robot(edit=relay_speed_slot)
    session = robot.gcs.session
    target = keys.slot_key(ROBOT, RELAY, "speed")
    relayed: list[float] = []
    timers: list[threading.Timer] = []

    def late(sample: zenoh.Sample) -> None:
        payload, encoding = sample.payload.to_bytes(), sample.encoding
        timer = threading.Timer(DELAY_S, lambda: (session.put(target, payload, encoding=encoding),
                                                  relayed.append(DELAY_S)))
        timers.append(timer)
        timer.start()

    sub = session.declare_subscriber(keys.slot_key(ROBOT, "ral", "speed"), late)
    try:
        up = robot.ensure_airborne()
        assert up.position is not None
        path = grid_path(up.position, [(1, 0), (2, 0), (2, 1)])
        mark = len(robot.commands())
        start = len(robot.events)
        reply = robot.gcs.send(ROBOT, t.Goto(waypoints=path, speed=SPEED))
        assert reply.accepted, reply.reason
        assert relayed, "the speed went through the delaying relay"
        wait_until(lambda: "ADD_WAYPOINT" in names(robot.commands()[mark:]), 20, "the path at the DSP")
        sent = robot.commands()[mark:]
        first_wp = names(sent).index("ADD_WAYPOINT")
        before = [c["fields"]["speed"] for c in sent[:first_wp] if c["name"] == "SET_SPEED"]
        assert before and before[-1] == pytest.approx(SPEED), (
            f"the DSP got {names(sent)}: SET_SPEED {SPEED} must precede the first ADD_WAYPOINT"
        )
        done = ended(robot, reply.task_id, 60, start)
        assert done.kind == "task_completed", done
        added = [c for c in robot.commands()[mark:] if c["name"] == "ADD_WAYPOINT"]
        assert len(added) == len(path), "exactly the path's waypoints were queued"
    finally:
        sub.undeclare()
        for timer in timers:
            timer.cancel()
