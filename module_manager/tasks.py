"""One task of each type at a time: which routes and modes a task sets, and what to restore when it ends.

Pure bookkeeping (no bus): ``start`` returns the route and mode changes to apply, ending the running task of the
same type first (its saved values are restored, then the new task's are applied over them); ``end`` returns the
values saved when the task started.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from module_manager.manifest import TaskDef
from module_manager.mri import ActiveTask

RouteKey = tuple[str, str]
"""(module, input slot)."""


@dataclass(frozen=True)
class Changes:
    routes: dict[RouteKey, int] = field(default_factory=dict)
    modes: dict[str, dict[str, int] | None] = field(default_factory=dict)
    """mode slot → fields to publish (None: the slot had no value before; nothing to publish)."""


@dataclass
class _Running:
    task: ActiveTask
    saved_routes: dict[RouteKey, int]
    saved_modes: dict[str, dict[str, int] | None]


class TaskBook:
    """The running task of each type and what it replaced."""

    def __init__(self, tasks: dict[str, TaskDef]) -> None:
        self.tasks = tasks
        self._running: dict[str, _Running] = {}

    def active(self) -> list[ActiveTask]:
        return [r.task for r in self._running.values()]

    def start(self, name: str, params: dict[str, str], now: float, routes: dict[RouteKey, int],
              modes: dict[str, dict[str, int] | None]) -> Changes:
        """Changes that start task ``name`` given the current ``routes``/``modes``; KeyError if unknown."""
        t = self.tasks[name]
        restore = self.end(t.type) if t.type in self._running else Changes()
        base_routes = {**routes, **restore.routes}
        base_modes = {**modes, **restore.modes}
        wanted_routes = {_split(target): number for target, number in t.routes.items()}
        saved_routes = {k: base_routes.get(k, -1) for k in wanted_routes}
        saved_modes = {slot: base_modes.get(slot) for slot in t.modes}
        self._running[t.type] = _Running(ActiveTask(task_type=t.type, name=name, params=dict(params), started=now),
                                         saved_routes, saved_modes)
        return Changes(routes={**restore.routes, **wanted_routes},
                       modes={**restore.modes, **{slot: dict(v) for slot, v in t.modes.items()}})

    def end(self, task_type: str) -> Changes:
        """Changes that end the running task of ``task_type``; KeyError if none runs."""
        running = self._running.pop(task_type)
        return Changes(routes=dict(running.saved_routes), modes=dict(running.saved_modes))


def _split(target: str) -> RouteKey:
    module, _, slot = target.partition(".")
    return module, slot
