"""One task per type: starting replaces the running task of the type, ending restores what was before."""

from __future__ import annotations

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
    ch = book.start("track", {}, 1.0, routes, modes)
    assert ch.routes == {("pt", "datos"): 5} and ch.modes == {"pt_mode": {"m": 1}}
    routes[("pt", "datos")] = 5
    modes["pt_mode"] = {"m": 1}
    ch = book.start("go", {"speed": "3"}, 2.0, routes, modes)
    assert ch.routes == {("pf", "datos"): 7}
    assert sorted(t.name for t in book.active()) == ["go", "track"], "one task per type, types independent"
    ch = book.start("hold", {}, 3.0, routes, modes)
    assert ch.routes == {("pt", "datos"): 1}, "the replaced task's route is restored"
    assert ch.modes == {"pt_mode": {"m": 2}}
    assert sorted(t.name for t in book.active()) == ["go", "hold"]
    modes["pt_mode"] = {"m": 2}
    routes[("pt", "datos")] = 1
    ch = book.end("pan_tilt")
    assert ch.modes == {"pt_mode": {"m": 0}}, "ending restores what was there before the first task of the type"
    assert [t.name for t in book.active()] == ["go"]
    assert book.end("movement").routes == {("pf", "datos"): 2}
