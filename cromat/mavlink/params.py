"""A robot's .conf values as MAVLink parameters (PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET).

MAVLink parameters are numbers named by at most 16 characters. Every numeric value of the .conf is one:
a top-level ``KEY: 8.0`` is ``KEY``; a list ``KEY: [37.4, -6.0, 3000]`` is ``KEY_1``, ``KEY_2``, ...; a group
``PID: ROLL { Kp=0.045 }`` is ``ROLL_KP`` (the group's name, not its type). A name longer than 16 characters keeps
its first 11 and gets ``_`` and four hex digits of its CRC-32 (stable, distinct). Text values (ports, modes, file
names) have no MAVLink form and are listed in :attr:`ParamTable.skipped`. No .conf value can be changed at run time
through the GRI (each module reads its .conf at start), so every PARAM_SET is refused with that reason.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path

from bbcs.conf.model import ConfDocument, ConfEntry

NAME_LEN = 16


@dataclass(frozen=True, slots=True)
class Param:
    name: str
    value: float
    source: str
    """``file:line KEY`` as written in the .conf."""


@dataclass
class ParamTable:
    conf: str = ""
    """The .conf file these came from (empty: the gateway was not given the robot's manifest)."""
    params: list[Param] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    """Entries with no numeric form (``file:line KEY``)."""
    _index: dict[str, int] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        self._index = {p.name: i for i, p in enumerate(self.params)}

    def find(self, name: str) -> tuple[int, Param] | None:
        i = self._index.get(name)
        return None if i is None else (i, self.params[i])

    def refusal(self, name: str) -> str:
        """Why PARAM_SET of ``name`` is refused."""
        if name not in self._index:
            where = f" in {Path(self.conf).name}" if self.conf else " (the gateway was given no manifest)"
            return f"PARAM_SET {name}: no such parameter{where}"
        p = self.params[self._index[name]]
        return (f"PARAM_SET {name} refused: {p.source} is read at start-up and cannot change at run time; "
                "edit the .conf and restart the robot")


def param_name(parts: list[str]) -> str:
    full = "_".join(parts).upper()
    if len(full) <= NAME_LEN:
        return full
    return f"{full[:NAME_LEN - 5]}_{zlib.crc32(full.encode()) & 0xFFFF:04X}"


def number(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _entry_params(prefix: list[str], entry: ConfEntry, path: str, table: ParamTable) -> None:
    where = f"{Path(path).name}:{entry.line} {entry.key}"
    values = entry.value if isinstance(entry.value, list) else [entry.value]
    numbers = [number(v) for v in values]
    if not values or any(n is None for n in numbers):
        table.skipped.append(where)
        return
    if not isinstance(entry.value, list):
        table.params.append(Param(param_name([*prefix, entry.key]), float(numbers[0]), where))  # type: ignore[arg-type]
        return
    for i, n in enumerate(numbers, 1):
        table.params.append(Param(param_name([*prefix, entry.key, str(i)]), float(n), f"{where}[{i}]"))  # type: ignore[arg-type]


def conf_params(doc: ConfDocument) -> ParamTable:
    """Every numeric value of ``doc``, in file order (top-level entries, then groups)."""
    table = ParamTable(conf=doc.path)
    for entry in doc.entries.values():
        _entry_params([], entry, doc.path, table)
    for group in doc.groups:
        for entry in group.entries.values():
            _entry_params([group.name], entry, doc.path, table)
    names = [p.name for p in table.params]
    if len(set(names)) != len(names):  # two .conf spellings of one name (Kp, KP): keep both, numbered
        seen: dict[str, int] = {}
        renamed = []
        for p in table.params:
            seen[p.name] = seen.get(p.name, 0) + 1
            name = p.name if seen[p.name] == 1 else param_name([p.name, str(seen[p.name])])
            renamed.append(Param(name, p.value, p.source))
        table.params = renamed
    table.__post_init__()
    return table
