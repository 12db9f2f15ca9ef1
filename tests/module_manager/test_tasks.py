"""One task per type: starting replaces the running task of the type, ending restores what was before."""

from __future__ import annotations

from bbcs.contracts import tasks as t
from module_manager.manifest import TaskDef
from module_manager.tasks import TaskBook

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
    restoring = TaskBook(tasks)  # the default: the value before is restored
    restoring.start("take_off", t.TakeOff(), 1.0, {}, {"quad": {"modo": 3}})
    assert restoring.end("movement").modes == {"quad": {"modo": 3}}
