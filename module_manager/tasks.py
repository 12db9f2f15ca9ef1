"""The task book: the one record of the running task of each type, with its typed parameters and how tasks ended.

Pure bookkeeping (no bus, no clock of its own): ``start`` returns the route and mode changes to apply, ending the
running task of the same type first (what its end changes, then the new task's values over them); ``end`` returns
what ending a task changes (:func:`ending`). Every change bumps ``version`` so a reader can tell a newer list from
an older one; ended tasks are kept (bounded) with their status and reason.

What ending a task does depends on its type (docs/gcs.md, "When a task ends"). A ``movement`` task moves the
robot: the mode it set is never re-published at its end, because the value before it belongs to a task that has
already ended (the take-off before a landing) and would fly again. Completed or replaced, nothing is sent (the
robot holds where the task left it, or the new task takes over), and the mode it set is withdrawn from its slot
unless the new task sets that slot (``Changes.withdraw``): a module restarted later must not fly it again;
failed, cancelled or aborted, the modes of the manifest's stop task (``hold``, else ``abort``) are sent: the
robot stops flying the rest of its path and station-keeps. Its routes go back to what they were (an input reads
its usual slot again; a route sends nothing by itself). Any other type (pan & tilt, perception) restores its
saved routes and modes: the gimbal goes back to its rest mode, or to the task of another type still running under it.

Routes and restored modes are layers: tasks of different types that set the same slot stack in the order they
started, over the slot's base (its value before the first of them). Ending a task removes its layer only: the slot
takes the value of the topmost task still running that sets it, else the base; a task ending under another one
changes nothing the one on top set. So the value a task saved is never brought back after the task it belonged to
has ended (a look-at started over a track, the track ended, then the look-at: the gimbal rests, it does not point at
the track's target with no task behind it).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import msgspec

from bbcs.contracts.tasks import Origin, TaskInfo, TaskParams, kind_of
from module_manager.manifest import TaskDef
from module_manager.task_data import kept

RouteKey = tuple[str, str]
"""(module, input slot)."""
MAX_ENDED = 32
MOVING_TYPE = "movement"
"""The task type whose tasks move the robot (every robot manifest's; docs/manifest.md)."""
STOP_TASKS = ("hold", "abort")
"""Manifest tasks that stop the robot where it is, in order of preference."""
STOPPING = frozenset({"failed", "cancelled", "aborted"})
"""How a moving task may end that leaves the robot flying the rest of it unless it is told to stop."""


def stop_task(tasks: dict[str, TaskDef]) -> str | None:
    """The manifest task that stops the robot's movement (``hold``, else ``abort``), or None."""
    return next((n for n in STOP_TASKS if n in tasks and tasks[n].type == MOVING_TYPE), None)


def ending(task_name: str, task_type: str, status: str, stop: str | None) -> str:
    """What ending task ``task_name`` of ``task_type`` with ``status`` does: ``"restore"`` (its saved routes and
    modes), ``"stop"`` (routes restored, the modes of the stop task ``stop`` sent) or ``"leave"`` (routes restored,
    no mode sent)."""
    if task_type != MOVING_TYPE:
        return "restore"
    if status in STOPPING and stop is not None and task_name not in STOP_TASKS:
        return "stop"
    return "leave"


@dataclass(frozen=True)
class Changes:
    routes: dict[RouteKey, int] = field(default_factory=dict)
    modes: dict[str, dict[str, Any] | None] = field(default_factory=dict)
    """mode slot → fields to publish (None: the slot had no value before; nothing to publish)."""
    withdraw: frozenset[str] = frozenset()
    """mode slots whose latched value is withdrawn (a delete: no value, nothing sent): the movement task that set
    it has ended and nothing replaced it, so a module restarted later does not run that task again."""


@dataclass
class _Running:
    task: TaskInfo
    saved_routes: dict[RouteKey, int]
    saved_modes: dict[str, dict[str, Any] | None]
    modes: dict[str, dict[str, Any]]
    """What the task set on each mode slot: the manifest's values, and the data they carry without their stream
    data (what it shows again when a task over it ends: module_manager/task_data.py)."""


class TaskBook:
    """The running task of each type, what it replaced, and the recently ended tasks."""

    def __init__(self, tasks: dict[str, TaskDef], no_restore: frozenset[str] = frozenset(),
                 streams: Mapping[str, frozenset[str]] | None = None,
                 data: Mapping[str, frozenset[str]] | None = None) -> None:
        """``no_restore``: mode slots whose old value is never re-published when a task ends (manifest
        ``restore = false``); a moving type's modes are never re-published whatever it says (:func:`ending`).
        ``streams``: per mode slot, its fields that carry stream data (never shown again). ``data``: per mode slot,
        every field that can carry a task's datum (module_manager/task_data.py): a slot's base never keeps one."""
        self.tasks = tasks
        self.no_restore = no_restore
        self.streams = dict(streams or {})
        self.data = dict(data or {})
        self.stop = stop_task(tasks)
        self._running: dict[str, _Running] = {}
        self._base_routes: dict[RouteKey, int] = {}
        self._base_modes: dict[str, dict[str, Any] | None] = {}
        """Each layered slot's value before the running tasks that set it: restored when the last of them ends."""
        self.ended: deque[TaskInfo] = deque(maxlen=MAX_ENDED)
        self.next_id = 1
        self.version = 0

    def active(self) -> list[TaskInfo]:
        return [self._running[t].task for t in sorted(self._running)]

    def running(self, task_type: str) -> TaskInfo | None:
        run = self._running.get(task_type)
        return None if run is None else run.task

    def start(self, name: str, params: TaskParams | None, now: float, routes: dict[RouteKey, int],
              modes: dict[str, dict[str, Any] | None], origin: Origin = "mri",
              replaced_as: str = "replaced") -> Changes:
        """Changes that start task ``name`` given the current ``routes``/``modes``; KeyError if unknown."""
        t = self.tasks[name]
        task = TaskInfo(id=self.next_id, name=name, task_type=t.type, kind=kind_of(params) if params else "",
                        params=params, started=now, origin=origin)
        self.next_id += 1
        restore = (self.end(t.type, now, replaced_as, f"{replaced_as} by task {task.id} ({name})")
                   if t.type in self._running else Changes())
        base_routes = {**routes, **restore.routes}
        base_modes = {**modes, **restore.modes}
        wanted_routes = {_split(target): number for target, number in t.routes.items()}
        saved_routes = {k: base_routes.get(k, -1) for k in wanted_routes}
        saved_modes = {slot: kept(base_modes.get(slot), self.streams.get(slot, frozenset()))
                       for slot in t.modes if slot not in self.no_restore}
        for key, value in saved_routes.items():
            if self._top_route(key) is None:
                self._base_routes[key] = value
        for slot, mode in saved_modes.items():
            if self._top_mode(slot) is None:  # no task under it: a datum still in the slot's value is an ended one's
                self._base_modes[slot] = kept(mode, self.data.get(slot, frozenset()))
        self._running[t.type] = _Running(task, saved_routes, saved_modes, {k: dict(v) for k, v in t.modes.items()})
        self.version += 1
        return Changes(routes={**restore.routes, **wanted_routes},
                       modes={**restore.modes, **{slot: dict(v) for slot, v in t.modes.items()}},
                       withdraw=restore.withdraw - set(t.modes))

    def carry(self, task_type: str, changes: Changes, data: Mapping[str, Mapping[str, Any]]) -> Changes:
        """``changes`` (what starting the running task of ``task_type`` changes) with ``data`` (mode slot → fields,
        :func:`module_manager.task_data.carry`) inside the task's modes; the task's layer keeps them without their
        stream data."""
        run = self._running[task_type]
        modes = dict(changes.modes)
        for slot, fields in data.items():
            full = {**run.modes[slot], **fields}
            modes[slot] = full
            run.modes[slot] = kept(full, self.streams.get(slot, frozenset())) or {}
        return Changes(routes=changes.routes, modes=modes, withdraw=changes.withdraw)

    def end(self, task_type: str, now: float = 0.0, status: str = "cancelled", detail: str = "") -> Changes:
        """Changes that end the running task of ``task_type`` (:func:`ending`); KeyError if none runs."""
        running = self._running.pop(task_type)
        self.ended.append(msgspec.structs.replace(running.task, status=status, ended=now, detail=detail))
        self.version += 1
        effect = ending(running.task.name, task_type, status, self.stop)
        routes = self._unlayer_routes(running)
        if effect == "restore":
            return Changes(routes=routes, modes=self._unlayer_modes(running))
        for slot in running.saved_modes:
            if self._top_mode(slot) is None:
                self._base_modes.pop(slot, None)
        stop = self.tasks[self.stop].modes if effect == "stop" and self.stop is not None else {}
        modes: dict[str, dict[str, Any] | None] = {slot: dict(v) for slot, v in stop.items()}
        withdraw = frozenset(self.tasks[running.task.name].modes) - set(modes)
        return Changes(routes=routes, modes=modes, withdraw=withdraw)

    def shown(self, slot: str) -> dict[str, Any] | None:
        """What the topmost running task that sets mode ``slot`` shows there (its data without stream data), or
        None when no running task sets it."""
        top = self._top_mode(slot)
        return None if top is None else dict(top.modes[slot])

    # --- layers: the topmost running task that sets a slot gives its value --------------------------------

    def _top_route(self, key: RouteKey) -> _Running | None:
        setters = [r for r in self._running.values()
                   if key in {_split(target) for target in self.tasks[r.task.name].routes}]
        return max(setters, key=lambda r: r.task.id, default=None)

    def _top_mode(self, slot: str) -> _Running | None:
        setters = [r for r in self._running.values() if slot in self.tasks[r.task.name].modes]
        return max(setters, key=lambda r: r.task.id, default=None)

    def _unlayer_routes(self, ended: _Running) -> dict[RouteKey, int]:
        """The routes that change when ``ended`` (no longer running) is taken off its layers."""
        out: dict[RouteKey, int] = {}
        for key, saved in ended.saved_routes.items():
            top = self._top_route(key)
            if top is None:
                out[key] = self._base_routes.pop(key, saved)
            elif top.task.id < ended.task.id:  # it was on top: the one under it shows again
                out[key] = next(n for target, n in self.tasks[top.task.name].routes.items() if _split(target) == key)
        return out

    def _unlayer_modes(self, ended: _Running) -> dict[str, dict[str, Any] | None]:
        """The restored modes that change when ``ended`` (no longer running) is taken off its layers."""
        out: dict[str, dict[str, Any] | None] = {}
        for slot, saved in ended.saved_modes.items():
            top = self._top_mode(slot)
            if top is None:
                out[slot] = self._base_modes.pop(slot, saved)
            elif top.task.id < ended.task.id:
                out[slot] = dict(top.modes[slot])
        return out

    def fail_needing(self, modules: set[str], uses: dict[str, set[str]], now: float, detail: str) -> list[Changes]:
        """End (failed) every running task whose manifest task uses one of ``modules``; the changes to apply."""
        out = []
        for task_type in sorted(self._running):
            if uses.get(self._running[task_type].task.name, set()) & modules:
                out.append(self.end(task_type, now, "failed", detail))
        return out


def _split(target: str) -> RouteKey:
    module, _, slot = target.partition(".")
    return module, slot
