"""Bad tasks from a ground station are rejected with a reason and change nothing: a waypoint out of range
(both outside the type's range and beyond the RAL's max range from the robot), an unknown task, and a task
kind this robot's manifest lacks (the launched manifest has no ``look_at`` task)."""

from __future__ import annotations

import re
import sys
import time
from pathlib import Path

import msgspec

from bbcs.contracts import gri
from bbcs.testing import wait_until

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_gcs_mission import ROBOT, SimRobot, connect, grid_path, launch_robot  # noqa: E402


def _without_look_at(text: str) -> str:
    out, n = re.subn(r"\[tasks\.look_at\]\n(?:[^\[\n][^\n]*\n|\n)*", "", text)
    assert n == 1
    return out


def _raw_task(robot: SimRobot, payload: bytes) -> gri.TaskReply:
    replies = list(robot.gcs.session.get(gri.task_key(ROBOT), payload=payload, timeout=10.0))
    oks = [r.ok for r in replies if r.ok is not None]
    assert len(oks) == 1
    return gri.decode_reply(oks[0].payload.to_bytes())


def test_bad_tasks_rejected_with_reason_state_unchanged(tmp_path: Path) -> None:
    la, record = launch_robot(tmp_path, edit=_without_look_at)
    gcs = None
    try:
        gcs = connect(la.port, "ground1")
        robot = SimRobot(la, gcs, record)
        before = robot.wait_state(
            lambda s: s.position is not None and s.link == "up" and bool(s.available),
            20,
            "state with position and the task list",
        )
        assert "look_at" not in before.available
        # the link-up event comes on its own key, with no order against the state that shows the link up: wait
        # for it (the start-up events come in order before it) so that what follows is only what the tasks caused
        robot.wait_event(lambda e: e.kind == "link_up", 20, "the link_up event")
        n_cmd = len(robot.commands())
        start = len(robot.events)
        pos = before.position
        assert pos is not None

        # waypoint out of the type's range: refused at decoding, msgspec says which field
        bad = msgspec.msgpack.encode(
            {"type": "goto", "waypoints": [{"lat": 91.0, "lon": pos.lon, "alt": 20.0}]}
        )
        reply = _raw_task(robot, bad)
        assert not reply.accepted and "lat" in reply.reason and "<= 90" in reply.reason
        # waypoint beyond max_range_m (5 km in the manifest) from the robot
        far = [*grid_path(pos)[:3], gri.Waypoint(lat=pos.lat + 0.1, lon=pos.lon, alt=pos.alt + 10)]
        far = [gri.Waypoint(lat=w.lat, lon=w.lon, alt=pos.alt + 10) for w in far]  # above the clearance
        reply = gcs.send(ROBOT, gri.FollowPath(waypoints=far))
        assert not reply.accepted and "waypoint 3" in reply.reason and "km from the robot" in reply.reason
        # unknown task
        reply = _raw_task(robot, msgspec.msgpack.encode({"type": "dance", "style": "salsa"}))
        assert not reply.accepted and "dance" in reply.reason
        # a task kind the robot lacks
        reply = gcs.send(ROBOT, gri.LookAt(lat=pos.lat, lon=pos.lon, alt=pos.alt))
        assert not reply.accepted and "has no task 'look_at'" in reply.reason
        answered = time.time()  # the RAL stamps its states with this same host clock

        # events travel on pub/sub, replies on queries: the last event may land after its reply
        def rejected() -> list[gri.GriEvent]:
            with robot.lock:
                return [e for e in robot.events[start:] if e.kind == "task_rejected"]

        wait_until(lambda: len(rejected()) >= 4, 15, "four task_rejected events")
        assert len(rejected()) == 4 and not [e for e in robot.events[start:] if e.kind != "task_rejected"]
        # a state the RAL made after the last rejection was answered: what the rejections (did not) change
        after = robot.wait_state(lambda s: s.stamp > max(answered, before.stamp + 0.5), 15, "a later state")
        assert after.tasks == before.tasks == []
        assert after.waypoints_queued == before.waypoints_queued
        assert after.airborne == before.airborne
        # a valid task still goes through afterwards, and nothing reached the DSP before it: its angles at the
        # DSP come after anything the refused tasks could have set off
        reply = gcs.send(ROBOT, gri.SetPanTilt(pan=10.0, tilt=0.0))
        assert reply.accepted, reply.reason
        wait_until(lambda: "SET_PT_ANGLES" in [c["name"] for c in robot.commands()[n_cmd:]], 20,
                   "the valid task's angles at the DSP")
        sent = [c["name"] for c in robot.commands()[n_cmd:]]
        assert not [n for n in sent if n in ("ADD_WAYPOINT", "SET_MODE", "SET_PT_TARGET", "SET_TRACKING")], sent
    finally:
        if gcs is not None:
            gcs.close()
        la.stop()
        la.cleanup()
