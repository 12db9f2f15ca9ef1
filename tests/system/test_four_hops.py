"""Issue 35, the command path in four hops (docs/bus.md, "The command path"), on the launched UAV
(``bbcs_conf/uav1_sim.toml``): a ground station's task reaches the module as one message, its mode with the task's
data inside, and the module's DSP commands follow at once. Judged by what crossed the bus (the manager's mode slot
and the RAL's data slots), what the DSP received (the simulator's record), what the aircraft did and what the
station was told, watching on after the task ends. Each robot flies in lockstep at ``--speed max``
(docs/simulation.md): the watches are simulated seconds, the same flight at any load.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

import msgspec

from bbcs import keys
from bbcs.contracts import gri, mri
from bbcs.contracts import tasks as t
from bbcs.contracts.pan_tilt import ModoFuncionamientoPT
from bbcs.contracts.path_follower import ControlModoSegCam
from bbcs.testing import wait_until

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_command_path import Factory, ended, make_robot, names, near  # noqa: E402,F401,F811
from test_gcs_mission import ROBOT, TIME_SCALE, grid_path  # noqa: E402

WATCH_AFTER_S = 20.0
"""Simulated seconds watched after a task ends: nothing unrequested may follow."""


def sim_time(state) -> float:  # type: ignore[no-untyped-def]
    """The simulator's time, as the telemetry stamps it."""
    return state.telemetry.stamp if state.telemetry is not None else 0.0


def listen(robot, module: str, slot: str, into: list, type_=None):  # type: ignore[no-untyped-def]
    decode = msgspec.msgpack.Decoder(type_).decode if type_ is not None else None
    return robot.gcs.session.declare_subscriber(
        keys.slot_key(ROBOT, module, slot),
        lambda s: into.append(decode(s.payload.to_bytes()) if decode else slot))


def test_a_goto_reaches_the_dsp_as_one_mode_message_and_nothing_follows(make_robot: Factory) -> None:  # noqa: F811
    robot = make_robot(speed="max")
    up = robot.ensure_airborne()
    assert up.position is not None
    modes: list[ControlModoSegCam] = []
    ral_data: list[str] = []
    subs = [listen(robot, "manager", "path_follower_mode", modes, ControlModoSegCam),
            *(listen(robot, "ral", slot, ral_data) for slot in ("speed", "path", "heading"))]
    try:
        mark, start = len(robot.commands()), len(robot.events)
        two = grid_path(up.position, [(0, 2), (0, 4)])
        reply = robot.gcs.send(ROBOT, t.Goto(waypoints=two, speed=4.0))
        assert reply.accepted, reply.reason
        done = ended(robot, reply.task_id, 60, start)
        assert done.kind == "task_completed", done
        assert near(robot.state, two[-1]), robot.state.position

        assert len(modes) == 1, f"one mode message for the task, got {len(modes)}"
        carried = modes[0]
        assert (carried.modo_o_comando, carried.modo_de_funcionamiento) == (0, 0)
        assert carried.velocidad is not None and carried.velocidad.speed == 4.0
        assert carried.datos is not None and [(p.latitud, p.longitud) for p in carried.datos.puntos] == [
            (w.lat, w.lon) for w in two], "the goto's waypoints inside the mode"
        assert ral_data == [], f"the RAL published the carried data again: {ral_data}"

        sent = robot.commands()[mark:]
        assert names(sent)[:6] == ["SET_MODE", "SET_TRACKING", "SET_SPEED", "INVALIDATE_PATH", "ADD_WAYPOINT",
                                   "ADD_WAYPOINT"], names(sent)
        assert sent[2]["fields"]["speed"] == 4.0, "the path flown at the task's speed, set before its waypoints"

        settled = len(robot.commands())
        end_stamp = sim_time(robot.state)
        robot.wait_state(lambda s: sim_time(s) >= end_stamp + WATCH_AFTER_S, 3 * WATCH_AFTER_S / TIME_SCALE + 30,
                         f"{WATCH_AFTER_S:g} s after the goto")
        assert names(robot.commands()[settled:]) == [], "a command after the task ended with nothing requested"
        assert near(robot.state, two[-1]), "the aircraft stays where the goto left it"
    finally:
        for sub in subs:
            sub.undeclare()


def test_a_pan_tilt_task_is_one_message_to_the_module(make_robot: Factory) -> None:  # noqa: F811
    """And a datum the manager cannot decode as its slot's struct (angles out of range, sent straight to the MRI,
    past the RAL's admission) refuses the task with the reason: no task starts, nothing reaches the DSP."""
    robot = make_robot(speed="max")
    modes: list[ModoFuncionamientoPT] = []
    ral_data: list[str] = []
    subs = [listen(robot, "manager", "pan_tilt_mode", modes, ModoFuncionamientoPT),
            listen(robot, "ral", "pt_datos", ral_data)]
    try:
        before = len(robot.commands())
        bad = mri.call(robot.gcs.session, ROBOT, "task", mri.SetTask(name="pan_tilt", data={
            "pt_datos": msgspec.Raw(msgspec.msgpack.encode({"ref_pan": 500.0, "ref_tilt": 0.0}))}))
        assert bad is not None and not bad.ok and "pt_datos datum is not a valid" in bad.reason, bad
        assert isinstance(bad.data, mri.TaskList) and not [x for x in bad.data.active if x.name == "pan_tilt"]
        assert modes == [] or all(m.datos is None for m in modes), "no mode carried the refused datum"

        mark = len(robot.commands())
        assert not [c for c in robot.commands()[before:mark] if c["name"].startswith("SET_PT")]
        reply = robot.gcs.send(ROBOT, t.SetPanTilt(pan=30.0, tilt=-20.0))
        assert reply.accepted, reply.reason
        robot.wait_state(lambda s: s.telemetry is not None and s.telemetry.pan_deg is not None
                         and s.telemetry.tilt_deg is not None and abs(s.telemetry.pan_deg - 30.0) < 1.0
                         and abs(s.telemetry.tilt_deg + 20.0) < 1.0, 20, "the gimbal at 30/-20")
        sent = robot.commands()[mark:]
        assert names(sent)[:2] == ["SET_PT_MODE", "SET_PT_ANGLES"], names(sent)
        assert modes and modes[-1].datos is not None and (modes[-1].datos.ref_pan, modes[-1].datos.ref_tilt) == (
            30.0, -20.0)
        assert ral_data == [], "the angles went inside the mode, not on the RAL's slot"

        # campaign seed 41, sequence 61: once the task has ended, a route swapped back to the slot its angles came
        # from is no reason to send anything (the rest mode carries no datum): nothing reaches the DSP
        cancelled = robot.gcs.send(ROBOT, gri.Cancel(task_type="pan_tilt"))
        assert cancelled.accepted, cancelled.reason
        wait_until(lambda: [c["fields"].get("mode") for c in robot.commands()[mark:]
                            if c["name"] == "SET_PT_MODE"][-1:] == [2], 20, "the gimbal back in its rest mode")
        rested = len(robot.commands())
        assert robot.gcs.route(ROBOT, "pan_tilt", "datos", 20).routes["pan_tilt"]["datos"] == 20
        assert robot.gcs.route(ROBOT, "pan_tilt", "datos", 10).routes["pan_tilt"]["datos"] == 10
        time.sleep(1.0)  # the swaps are answered after the module acknowledged them: anything they sent is out
        assert names(robot.commands()[rested:]) == [], "a route swap sent a command with no task behind it"
    finally:
        for sub in subs:
            sub.undeclare()


def test_a_path_follower_restarted_mid_path_does_not_fly_the_path_again(make_robot: Factory) -> None:  # noqa: F811
    """The mode slot keeps the task's mode for a restarted module, but not the path it carried (a stream is
    delivered once): the DSP flies on with its own queue and the task, which survives the path follower's restart,
    completes at the path's end."""
    robot = make_robot(speed="max")
    up = robot.ensure_airborne()
    assert up.position is not None
    path = grid_path(up.position, [(i, 0) for i in range(1, 6)], scale=2)
    start, sent_from = len(robot.events), len(robot.commands())
    reply = robot.gcs.send(ROBOT, t.FollowPath(waypoints=path, speed=5.0))
    assert reply.accepted, reply.reason
    wait_until(lambda: names(robot.commands()[sent_from:]).count("ADD_WAYPOINT") == len(path), 20,
               "the whole path at the DSP")
    robot.wait_state(lambda s: s.waypoints_queued is not None and s.waypoints_queued <= 3, 40, "past the first "
                     "waypoints")
    follower = next(m for m in robot.gcs.modules(ROBOT).modules if m.name == "path_follower")
    assert follower.pid is not None
    mark = len(robot.commands())
    os.kill(follower.pid, signal.SIGKILL)
    robot.wait_state(lambda s: any(m.name == "path_follower" and m.state == "up" and m.restarts >= 1
                                   for m in s.modules), 60, "the path follower restarted")
    done = ended(robot, reply.task_id, 90, start)
    assert done.kind == "task_completed", done
    after = names(robot.commands()[mark:])
    assert not {"INVALIDATE_PATH", "ADD_WAYPOINT"} & set(after), f"the path was sent again: {after}"
    assert after[:3] == ["SET_MODE", "SET_TRACKING", "SET_SPEED"], f"the restarted module's mode and speed: {after}"
    assert near(robot.state, path[-1]), "flown to the path's end"
