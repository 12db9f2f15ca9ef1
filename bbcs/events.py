"""The typed events a module's one loop handles, in arrival order, on one thread (as in dora's node API).

Zenoh's callbacks only enqueue; the loop decodes (= validates) and calls the module's code. ``bbcs.testing``'s
``ModuleDriver`` feeds the same events to a module without a router.
"""

from __future__ import annotations

from typing import Any

import msgspec


class Input(msgspec.Struct, frozen=True):
    """A datum on input ``slot``: a struct (validated as if it came off the wire) or the raw msgpack bytes."""

    slot: str
    value: Any


class Tick(msgspec.Struct, frozen=True):
    """The module's ``tick_period`` elapsed: ``on_tick`` runs."""


class RouteChange(msgspec.Struct, frozen=True):
    """A CONTROL_ENTRADA: routed input slot → slot number (-1: ignore). Applied all-or-none at the switch point."""

    routes: dict[str, int]


class Stop(msgspec.Struct, frozen=True):
    """Stop the loop: ``on_stop`` runs, then the bus is closed."""


Event = Input | Tick | RouteChange | Stop
