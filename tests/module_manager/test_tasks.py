"""One task per type: starting replaces the running task of the type; ending a pan & tilt or perception task
restores what was before, ending a movement task never brings back the task before it (it stops, or leaves the
robot where the task put it)."""

from __future__ import annotations

from bbcs.contracts import tasks as t
from module_manager.manifest import TaskDef
from module_manager.tasks import TaskBook, ending, stop_task

TASKS = {
    "track": TaskDef(type="pan_tilt", routes={"pt.datos": 5}, modes={"pt_mode": {"m": 1}}),
    "hold": TaskDef(type="pan_tilt", routes={}, modes={"pt_mode": {"m": 2}}),
    "go": TaskDef(type="movement", routes={"pf.datos": 7}),
}


def test_start_end_restore_and_replace():
    book = TaskBook(TASKS)
    routes = {("pt", "datos"): 1, ("pf", "datos"): 2}
    modes = {"pt_mode": {"m": 0}}
    ch = book.start("track", t.Track(), 1.0, routes, modes)
    assert ch.routes == {("pt", "datos"): 5} and ch.modes == {"pt_mode": {"m": 1}}
    routes[("pt", "datos")] = 5
    modes["pt_mode"] = {"m": 1}
    go = t.Goto(waypoints=[t.Waypoint(lat=37.0, lon=-6.0, alt=30.0)], speed=3.0)
    ch = book.start("go", go, 2.0, routes, modes, origin="gcs")
    assert ch.routes == {("pf", "datos"): 7}
    assert sorted(t.name for t in book.active()) == ["go", "track"], "one task per type, types independent"
    ch = book.start("hold", None, 3.0, routes, modes)
    assert ch.routes == {("pt", "datos"): 1}, "the replaced task's route is restored"
    assert ch.modes == {"pt_mode": {"m": 2}}
    assert sorted(t.name for t in book.active()) == ["go", "hold"]
    modes["pt_mode"] = {"m": 2}
    routes[("pt", "datos")] = 1
    ch = book.end("pan_tilt")
    assert ch.modes == {"pt_mode": {"m": 0}}, "ending restores what was there before the first task of the type"
    assert [t.name for t in book.active()] == ["go"]
    assert book.end("movement").routes == {("pf", "datos"): 2}


def test_the_book_keeps_typed_parameters_ids_and_how_each_task_ended():
    book = TaskBook(TASKS)
    go = t.Goto(waypoints=[t.Waypoint(lat=37.0, lon=-6.0, alt=30.0)], speed=3.0)
    book.start("go", go, 1.0, {}, {}, origin="gcs")
    first = book.running("movement")
    assert first is not None and first.params == go and first.kind == "goto" and first.origin == "gcs"
    v = book.version
    book.start("go", go, 2.0, {}, {})
    second = book.running("movement")
    assert second is not None and second.id == first.id + 1 and book.version > v
    assert [(e.id, e.status) for e in book.ended] == [(first.id, "replaced")]
    assert f"task {second.id}" in book.ended[-1].detail
    book.end("movement", 3.0, "failed", "module dsp exited")
    assert book.ended[-1].status == "failed" and book.ended[-1].detail == "module dsp exited"
    assert book.running("movement") is None


def test_tasks_that_use_a_failed_module_fail():
    book = TaskBook(TASKS)
    book.start("track", t.Track(), 1.0, {}, {})
    book.start("go", None, 1.0, {}, {})
    changes = book.fail_needing({"pt"}, {"track": {"pt"}, "go": {"pf"}}, 2.0, "module pt exited")
    assert len(changes) == 1 and [x.name for x in book.active()] == ["go"]
    assert book.ended[-1].name == "track" and book.ended[-1].status == "failed"


def test_a_mode_slot_without_restore_is_left_as_the_module_reached_it():
    """Movement commands (take off, land) are one-shot: ending one must not re-send the command before it."""
    tasks = {"take_off": TaskDef(type="movement", modes={"quad": {"modo": 2}}),
             "land": TaskDef(type="movement", modes={"quad": {"modo": 3}})}
    book = TaskBook(tasks, no_restore=frozenset({"quad"}))
    modes: dict = {"quad": None}
    assert book.start("take_off", t.TakeOff(height=5.0), 1.0, {}, modes).modes == {"quad": {"modo": 2}}
    modes["quad"] = {"modo": 2}
    assert book.end("movement", 2.0, "completed").modes == {}, "a completed take-off re-sends nothing"
    assert book.start("land", t.Land(), 3.0, {}, modes).modes == {"quad": {"modo": 3}}
    modes["quad"] = {"modo": 3}
    ch = book.start("take_off", t.TakeOff(height=2.0), 4.0, {}, modes)
    assert ch.modes == {"quad": {"modo": 2}}, "replacing sends only the new command, not the old one restored"
    assert book.end("movement", 5.0, "completed").modes == {}
    by_rule = TaskBook(tasks)  # without restore = false: a movement task's mode is never restored all the same
    by_rule.start("take_off", t.TakeOff(), 1.0, {}, {"quad": {"modo": 3}})
    assert by_rule.end("movement").modes == {}
    panning = TaskBook({"look": TaskDef(type="pan_tilt", modes={"pt": {"m": 1}})})  # other types: restored
    panning.start("look", None, 1.0, {}, {"pt": {"m": 2}})
    assert panning.end("pan_tilt").modes == {"pt": {"m": 2}}


# ------------------------------------------------------------------ ending a movement task (issue 30, case 1)

PF = {"modo_o_comando": 0}
UAV = {  # as bbcs_conf/uav1_sim.toml: every movement task drives the path follower's mode slot
    "take_off": TaskDef(type="movement", modes={"pf_mode": {**PF, "modo_de_funcionamiento": 4}}),
    "land": TaskDef(type="movement", modes={"pf_mode": {**PF, "modo_de_funcionamiento": 5}}),
    "goto": TaskDef(type="movement", routes={"pf.datos": 11}, modes={"pf_mode": {**PF, "modo_de_funcionamiento": 0}}),
    "survey": TaskDef(type="movement", routes={"pf.datos": 30}, modes={"pf_mode": {**PF, "modo_de_funcionamiento": 0}}),
    "hold": TaskDef(type="movement", modes={"pf_mode": {"modo_o_comando": 1, "numero_de_comando": 0}}),
    "abort": TaskDef(type="movement", modes={"pf_mode": {"modo_o_comando": 1, "numero_de_comando": 0}}),
    "look_at": TaskDef(type="pan_tilt", routes={"pt.datos": 10}, modes={"pt_mode": {"m": 1}}),
    "track": TaskDef(type="perception", routes={"pt.datos": 20}, modes={"pt_mode": {"m": 1}}),
}
HOLD = {"pf_mode": {"modo_o_comando": 1, "numero_de_comando": 0}}
GOTO = t.Goto(waypoints=[t.Waypoint(lat=37.41, lon=-6.0, alt=40.0)], speed=5.0)


class Robot:
    """The manager's side of the book: the routes and modes as they stand, changed by what the book returns."""

    def __init__(self, tasks: dict[str, TaskDef] = UAV) -> None:
        self.book = TaskBook(tasks)
        self.routes = {("pf", "datos"): 11, ("pt", "datos"): 10}
        self.modes: dict = {"pf_mode": None, "pt_mode": {"m": 2}}
        self.sent: list[dict] = []

    def apply(self, ch) -> None:  # noqa: ANN001
        self.routes.update(ch.routes)
        for slot, value in ch.modes.items():
            if value is not None:
                self.modes[slot] = value
                self.sent.append({slot: value})
        for slot in ch.withdraw:  # what a module (re)started now would get: nothing
            self.modes[slot] = None

    def start(self, name: str, params=None, replaced_as: str = "replaced") -> None:  # noqa: ANN001
        self.apply(self.book.start(name, params, 0.0, dict(self.routes), dict(self.modes), replaced_as=replaced_as))

    def end(self, task_type: str, status: str) -> list[dict]:
        before = len(self.sent)
        self.apply(self.book.end(task_type, 1.0, status))
        return self.sent[before:]


def test_the_rule_per_type_and_status():
    assert stop_task(UAV) == "hold", "hold is preferred to abort as the stop"
    assert stop_task({"abort": UAV["abort"]}) == "abort"
    assert stop_task({"look_at": UAV["look_at"]}) is None
    assert stop_task(TASKS) is None, "a pan & tilt task named hold does not stop the movement"
    for status in ("completed", "replaced"):
        assert ending("goto", "movement", status, "hold") == "leave"
    for status in ("failed", "cancelled", "aborted"):
        assert ending("goto", "movement", status, "hold") == "stop"
        assert ending("goto", "movement", status, None) == "leave", "no stop task: still never the task before"
        assert ending("hold", "movement", status, "hold") == "leave", "a stopped robot is not told to stop again"
        assert ending("abort", "movement", status, "hold") == "leave"
        assert ending("look_at", "pan_tilt", status, "hold") == "restore"
    assert ending("track", "perception", "completed", "hold") == "restore"


def test_a_completed_land_never_sends_the_take_off_again():
    robot = Robot()
    robot.start("take_off", t.TakeOff(height=10.0))
    assert robot.end("movement", "completed") == [], "a completed take-off leaves the aircraft hovering there"
    robot.start("land", t.Land())
    assert robot.sent[-1] == {"pf_mode": {**PF, "modo_de_funcionamiento": 5}}
    assert robot.end("movement", "completed") == [], "after touchdown nothing is sent: no SET_MODE 4"


def test_a_completed_goto_leaves_the_aircraft_where_it_arrived():
    robot = Robot()
    robot.start("take_off", t.TakeOff(height=10.0))
    robot.start("goto", GOTO)
    assert robot.end("movement", "completed") == [], "no drop back into take-off mode"
    assert robot.routes[("pf", "datos")] == 11


def test_a_failed_or_cancelled_path_stops_where_it_is_never_in_the_task_before():
    for status in ("failed", "cancelled", "aborted"):
        robot = Robot()
        robot.start("take_off", t.TakeOff(height=10.0))
        robot.start("survey", t.Survey(polygon=[t.Vertex(lat=37.41, lon=-6.0), t.Vertex(lat=37.411, lon=-6.0),
                                                t.Vertex(lat=37.411, lon=-6.001)], height=30.0))
        assert robot.routes[("pf", "datos")] == 30
        assert robot.end("movement", status) == [HOLD], f"{status}: an explicit hold, no mode of its own"
        assert robot.routes[("pf", "datos")] == 11, "the follower reads the RAL's path slot again"


def test_abort_and_its_completion_leave_the_aircraft_holding():
    robot = Robot()
    robot.start("take_off", t.TakeOff(height=10.0))
    robot.start("goto", GOTO)
    robot.start("abort", None, replaced_as="aborted")
    assert robot.sent[-1] == HOLD and robot.book.ended[-1].status == "aborted"
    assert robot.end("movement", "completed") == [], "the abort done: no take-off mode afterwards"
    robot.start("hold", t.Hold())
    assert robot.end("movement", "cancelled") == [], "cancelling a hold sends nothing: it already holds"


def test_the_mode_of_an_ended_movement_task_is_withdrawn_not_kept_for_a_restarted_module():
    """Issue 30: a path follower restarted after a completed take-off got the take-off mode from its slot and sent
    SET_MODE TAKE_OFF with no task running. The slot holds a movement task's mode while it runs, nothing after."""
    take_off = {"pf_mode": {**PF, "modo_de_funcionamiento": 4}}
    for status in ("completed", "failed", "cancelled", "aborted"):
        robot = Robot({n: d for n, d in UAV.items() if n not in ("hold", "abort")})  # no stop task: "leave"
        robot.start("take_off", t.TakeOff(height=10.0))
        assert {"pf_mode": robot.modes["pf_mode"]} == take_off, "running: a restarted follower still gets it"
        assert robot.end("movement", status) == [] and robot.modes["pf_mode"] is None, status
    robot = Robot()
    robot.start("take_off", t.TakeOff(height=10.0))
    robot.start("goto", GOTO)
    assert not robot.book.start("land", t.Land(), 0.0, {}, dict(robot.modes)).withdraw, \
        "replaced by a task that sets the slot: its mode is the new task's"
    robot = Robot()
    robot.start("goto", GOTO)
    assert robot.end("movement", "failed") == [HOLD] and robot.modes["pf_mode"] == HOLD["pf_mode"], \
        "a failed task's hold stays in the slot: a restarted follower holds again"
    robot.start("look_at", t.LookAt(lat=37.41, lon=-6.0, alt=12.0))
    robot.end("pan_tilt", "cancelled")
    assert robot.modes["pt_mode"] == {"m": 2}, "other types restore, never withdraw"
    assert robot.modes["pf_mode"] == HOLD["pf_mode"]
    replaced = TaskBook({"go": TaskDef(type="movement", modes={"a": {"m": 1}, "b": {"m": 1}}),
                         "turn": TaskDef(type="movement", modes={"a": {"m": 2}})})
    replaced.start("go", None, 0.0, {}, {"a": None, "b": None})
    ch = replaced.start("turn", None, 1.0, {}, {"a": {"m": 1}, "b": {"m": 1}})
    assert ch.withdraw == {"b"} and ch.modes == {"a": {"m": 2}}, "a slot the new task leaves alone is withdrawn"


def test_a_replacing_task_sends_only_its_own_mode():
    robot = Robot()
    robot.start("goto", GOTO)
    robot.start("land", t.Land())
    assert robot.sent[-1] == {"pf_mode": {**PF, "modo_de_funcionamiento": 5}} and len(robot.sent) == 2


def test_a_module_failure_stops_the_movement_and_restores_the_gimbal():
    robot = Robot()
    robot.start("goto", GOTO)
    robot.start("look_at", t.LookAt(lat=37.41, lon=-6.0, alt=12.0))
    changes = robot.book.fail_needing({"dsp"}, {"goto": {"dsp"}, "look_at": {"dsp"}}, 2.0, "module dsp exited")
    for ch in changes:
        robot.apply(ch)
    assert robot.sent[-2:] == [HOLD, {"pt_mode": {"m": 2}}] or robot.sent[-2:] == [{"pt_mode": {"m": 2}}, HOLD]
    assert robot.routes[("pt", "datos")] == 10


def test_continuous_pan_tilt_and_perception_tasks_restore_what_was_under_them():
    robot = Robot()
    robot.start("track", t.Track())
    assert robot.routes[("pt", "datos")] == 20
    robot.start("look_at", t.LookAt(lat=37.41, lon=-6.0, alt=12.0))
    assert robot.end("pan_tilt", "completed") == [{"pt_mode": {"m": 1}}], "back to the track still running"
    assert robot.routes[("pt", "datos")] == 20
    assert robot.end("perception", "cancelled") == [{"pt_mode": {"m": 2}}], "back to the gimbal's rest mode"
    assert robot.routes[("pt", "datos")] == 10


def test_a_task_ending_under_another_changes_nothing_and_the_last_one_restores_the_rest_mode():
    """Campaign seed 7, sequences 17-23: a look-at started over a track saved the track's target mode; the track
    ended (its vision module killed) and put the gimbal to rest under the running look-at; then the look-at ended
    and brought back the track's target mode, with no task behind it: the gimbal followed whatever reached its
    input (a route swap to vision's target, later a 0°/0° datum) and the DSP got pointing commands of no task."""
    robot = Robot()
    robot.start("track", t.Track())
    robot.start("look_at", t.LookAt(lat=37.41, lon=-6.0, alt=12.0))
    assert robot.end("perception", "failed") == [], "the look-at on top keeps the gimbal"
    assert robot.routes[("pt", "datos")] == 10 and robot.modes["pt_mode"] == {"m": 1}
    assert robot.end("pan_tilt", "completed") == [{"pt_mode": {"m": 2}}], "no task left: the rest mode"
    assert robot.routes[("pt", "datos")] == 10
    # and the same with the look-at under the track
    robot.start("look_at", t.LookAt(lat=37.41, lon=-6.0, alt=12.0))
    robot.start("track", t.Track())
    assert robot.end("pan_tilt", "cancelled") == [] and robot.routes[("pt", "datos")] == 20
    assert robot.end("perception", "cancelled") == [{"pt_mode": {"m": 2}}] and robot.routes[("pt", "datos")] == 10


def test_a_task_under_another_shows_its_carried_state_data_again_but_never_its_path() -> None:
    """The data a task's mode carried (task_data.py) are part of its layer: when a task over it ends, its mode is
    shown again with them (the gimbal points at the task's angles again), but a stream datum (a path) is never
    flown twice."""
    tasks = {
        "angles": TaskDef(type="pan_tilt", routes={"pt.datos": 10}, modes={"pt_mode": {"m": 0}}),
        "track": TaskDef(type="perception", routes={"pt.datos": 20}, modes={"pt_mode": {"m": 1}}),
    }
    book = TaskBook(tasks, streams={"pt_mode": frozenset({"path"})})
    ch = book.start("angles", t.SetPanTilt(pan=30.0, tilt=-20.0), 1.0, {("pt", "datos"): 10}, {"pt_mode": {"m": 2}})
    ch = book.carry("pan_tilt", ch, {"pt_mode": {"datos": {"ref_pan": 30.0}, "path": [1, 2]}})
    assert ch.modes == {"pt_mode": {"m": 0, "datos": {"ref_pan": 30.0}, "path": [1, 2]}}, "sent whole"
    book.start("track", t.Track(), 2.0, {("pt", "datos"): 10}, {"pt_mode": ch.modes["pt_mode"]})
    back = book.end("perception")
    assert back.modes == {"pt_mode": {"m": 0, "datos": {"ref_pan": 30.0}}}
    assert back.routes == {("pt", "datos"): 10}
    assert book.end("pan_tilt").modes == {"pt_mode": {"m": 2}}, "the rest mode, as before the first task"


def test_a_slot_base_never_keeps_the_datum_of_an_ended_task() -> None:
    """Campaign seed 41, sequences 155, 179, 197: the gimbal's mode slot still held an ended pan & tilt task's
    angles when a track started with nothing under it; that value became the slot's base, and the track's end (a
    pan & tilt killed) put it back: the restarted pan & tilt pointed at angles no task had asked for. A slot's base
    is the value before any running task set it, so a datum in it is an ended task's: it is never kept."""
    tasks = {
        "angles": TaskDef(type="pan_tilt", routes={"pt.datos": 10}, modes={"pt_mode": {"m": 0}}),
        "track": TaskDef(type="perception", routes={"pt.datos": 20}, modes={"pt_mode": {"m": 1}}),
    }
    book = TaskBook(tasks, data={"pt_mode": frozenset({"datos"})})
    left = {"pt_mode": {"m": 0, "datos": {"ref_pan": -70.0, "ref_tilt": 0.0}}}
    book.start("track", t.Track(), 1.0, {("pt", "datos"): 10}, left)
    assert book.shown("pt_mode") == {"m": 1}
    assert book.end("perception", 2.0, "failed").modes == {"pt_mode": {"m": 0}}, "the mode, not the datum"
    assert book.shown("pt_mode") is None, "no task sets the slot"


def test_shown_is_the_running_layer_with_its_carried_state_data() -> None:
    tasks = {"angles": TaskDef(type="pan_tilt", routes={"pt.datos": 10}, modes={"pt_mode": {"m": 0}})}
    book = TaskBook(tasks, streams={"pt_mode": frozenset({"path"})}, data={"pt_mode": frozenset({"datos", "path"})})
    ch = book.start("angles", t.SetPanTilt(pan=30.0, tilt=-20.0), 1.0, {("pt", "datos"): 10}, {"pt_mode": {"m": 2}})
    book.carry("pan_tilt", ch, {"pt_mode": {"datos": {"ref_pan": 30.0}, "path": [1]}})
    assert book.shown("pt_mode") == {"m": 0, "datos": {"ref_pan": 30.0}}
    assert book.end("pan_tilt", 2.0).modes == {"pt_mode": {"m": 2}}
    assert book.shown("pt_mode") is None
