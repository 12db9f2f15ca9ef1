"""A task's data inside its modes: the four-hop command path (docs/bus.md, "The command path").

The RAL hands the manager a task's data by the names of its own output slots (``SetTask.data``). Each datum goes
where the routes would have taken it: the module input that reads the RAL slot's number once the task's routes
apply. When that module's mode message has a field of the input's name (``ControlModoSegCam.datos``), the datum
rides inside the task's mode: the module acts on mode and data at once, with no acknowledgement round trip and no
second message to keep in order. All or none: if one datum has no such input, none is carried and the RAL
publishes them all on its slots, in its own order (speed acknowledged before the path), as before.

Pure functions: no bus, no clock.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

RouteKey = tuple[str, str]
"""(module, input slot)."""


def carry(data: Mapping[int, Any], task_modes: Iterable[str], mode_module: Mapping[str, str],
          mode_fields: Mapping[str, frozenset[str]],
          routes: Mapping[RouteKey, int]) -> dict[str, dict[str, Any]] | None:
    """For each of the task's mode slots, the data (by slot number) its module's inputs read under ``routes``, as
    fields of that mode named after the inputs. ``{}`` when there are no data; None when some datum reaches no input
    a mode of the task can carry (then none is carried)."""
    out: dict[str, dict[str, Any]] = {}
    reached: set[int] = set()
    for slot in task_modes:
        module, fields = mode_module[slot], mode_fields[slot]
        for (name, inp), number in sorted(routes.items()):
            if name == module and inp in fields and number in data:
                out.setdefault(slot, {})[inp] = data[number]
                reached.add(number)
    return out if reached == set(data) else None


def kept(value: Mapping[str, Any] | None, streams: frozenset[str]) -> dict[str, Any] | None:
    """A mode value as the slot keeps it once delivered: without its stream data (a path is flown once; a module
    restarted later, or a layer shown again, must not fly it again). State data (a speed, angles) stay."""
    if value is None:
        return None
    return {k: v for k, v in value.items() if k not in streams or v is None}
