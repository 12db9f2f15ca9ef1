"""The task book: the one record of the running task of each type, with its typed parameters and how tasks ended.

Pure bookkeeping (no bus, no clock of its own): ``start`` returns the route and mode changes to apply, ending the
running task of the same type first (its saved values are restored, then the new task's are applied over them);
``end`` returns the values saved when the task started. Every change bumps ``version`` so a reader can tell a newer
list from an older one; ended tasks are kept (bounded) with their status and reason.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import msgspec

from bbcs.contracts.tasks import Origin, TaskInfo, TaskParams, kind_of
from module_manager.manifest import TaskDef

RouteKey = tuple[str, str]
"""(module, input slot)."""
MAX_ENDED = 32


@dataclass(frozen=True)
class Changes:
    routes: dict[RouteKey, int] = field(default_factory=dict)
    modes: dict[str, dict[str, int] | None] = field(default_factory=dict)
    """mode slot → fields to publish (None: the slot had no value before; nothing to publish)."""


@dataclass
class _Running:
    task: TaskInfo
    saved_routes: dict[RouteKey, int]
    saved_modes: dict[str, dict[str, int] | None]


class TaskBook:
    """The running task of each type, what it replaced, and the recently ended tasks."""

    def __init__(self, tasks: dict[str, TaskDef], no_restore: frozenset[str] = frozenset()) -> None:
        """``no_restore``: mode slots whose old value is never re-published when a task ends (manifest
        ``restore = false``: one-shot movement commands)."""
        self.tasks = tasks
        self.no_restore = no_restore
        self._running: dict[str, _Running] = {}
        self.ended: deque[TaskInfo] = deque(maxlen=MAX_ENDED)
        self.next_id = 1
        self.version = 0

    def active(self) -> list[TaskInfo]:
        return [self._running[t].task for t in sorted(self._running)]

    def running(self, task_type: str) -> TaskInfo | None:
        run = self._running.get(task_type)
        return None if run is None else run.task

    def start(self, name: str, params: TaskParams | None, now: float, routes: dict[RouteKey, int],
              modes: dict[str, dict[str, int] | None], origin: Origin = "mri",
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
        saved_modes = {slot: base_modes.get(slot) for slot in t.modes if slot not in self.no_restore}
        self._running[t.type] = _Running(task, saved_routes, saved_modes)
        self.version += 1
        return Changes(routes={**restore.routes, **wanted_routes},
                       modes={**restore.modes, **{slot: dict(v) for slot, v in t.modes.items()}})

    def end(self, task_type: str, now: float = 0.0, status: str = "cancelled", detail: str = "") -> Changes:
        """Changes that end the running task of ``task_type``; KeyError if none runs."""
        running = self._running.pop(task_type)
        self.ended.append(msgspec.structs.replace(running.task, status=status, ended=now, detail=detail))
        self.version += 1
        return Changes(routes=dict(running.saved_routes), modes=dict(running.saved_modes))

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
