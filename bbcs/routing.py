"""The robot's slot table (slot number → module/slot and struct type) and route checking.

CONTROL_ENTRADA structs carry slot *numbers*; the table, defined by the manifest, turns a number into the key
expression to read and the struct type found there. A route is refused, and the old one kept, when the number
is missing or the types differ. ``-1`` means "ignore this input".
"""

from __future__ import annotations

import msgspec

from bbcs import keys
from bbcs.errors import BusErrorCode, RouteError

IGNORE = -1
"""The slot number that means "read nothing on this input"."""


class SlotRef(msgspec.Struct, frozen=True, kw_only=True):
    """One row of the slot table."""

    module: str
    slot: str
    type: str
    """``package.module:Class`` of the struct carried there."""
    robot: str | None = None
    """Another robot's slot; ``None`` is the robot the table belongs to."""

    def key(self, robot: str) -> str:
        return keys.slot_key(self.robot or robot, self.module, self.slot)


class SlotTable(msgspec.Struct, frozen=True, kw_only=True):
    """All numbered slots of one robot."""

    robot: str
    slots: dict[int, SlotRef] = msgspec.field(default_factory=dict)

    def resolve(self, number: int, expected_type: str) -> str | None:
        """The key to read for ``number`` (None for -1); RouteError with a code when it cannot be routed."""
        if number == IGNORE:
            return None
        ref = self.slots.get(number)
        if ref is None:
            raise RouteError(f"slot {number} is not in robot {self.robot!r}'s slot table",
                             BusErrorCode.ROUTE_UNKNOWN_SLOT)
        if ref.type != expected_type:
            raise RouteError(f"slot {number} ({ref.module}/{ref.slot}) carries {ref.type}, "
                             f"not {expected_type}", BusErrorCode.ROUTE_TYPE_MISMATCH)
        return ref.key(self.robot)

    def number_of(self, module: str, slot: str) -> int | None:
        for number, ref in self.slots.items():
            if ref.module == module and ref.slot == slot and ref.robot is None:
                return number
        return None




class RouteAck(msgspec.Struct, frozen=True, kw_only=True):
    """What a module publishes on ``@route`` after a CONTROL_ENTRADA: the routes now in force, or why not."""

    module: str
    accepted: bool
    routes: dict[str, int]
    """input slot name → slot number now read (-1: ignored)."""
    request: dict[str, int] = msgspec.field(default_factory=dict)
    """The CONTROL_ENTRADA fields that were asked for."""
    reason: str = ""
    restart_count: int = 0
