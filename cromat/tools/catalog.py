"""What is on a robot's bus: every slot's key, struct type, JSON Schema, writer, readers and routes.

Learned from the bus itself: liveliness tokens name the modules alive; each module's ``@schema`` queryable
describes its slots and routes (queried one module at a time, accepting a reply on the module's own key or on
the query's key); the manager's ``routes`` answer turns slot numbers into names. Keys of the bus's own
bookkeeping (GRI state and events, the manager's robot state, route acknowledgements, heartbeats) have known
types. A key nobody describes is still decoded as plain msgpack.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from typing import Any

import msgspec
import zenoh

from bbcs import keys
from bbcs.codec import json_schema, resolve_type, type_name
from bbcs.contracts import gri, mri
from bbcs.module import Heartbeat
from bbcs.routing import RouteAck

ENCODING_PREFIX = "application/msgpack"


@dataclass
class SlotInfo:
    """One key on the bus and what is known about it."""

    key: str
    type: str = ""
    """``package.module:Class`` ("" when unknown)."""
    schema: dict[str, Any] = field(default_factory=dict)
    kind: str = ""
    safety: str = ""
    writers: list[str] = field(default_factory=list)
    readers: list[str] = field(default_factory=list)
    """``module.input`` (with ``#number`` when routed through the slot table)."""
    number: int | None = None
    """Slot-table number, when the key has one."""

    @property
    def short_type(self) -> str:
        return self.type.rpartition(":")[2] or "?"


@dataclass
class ModuleInfo:
    robot: str
    name: str
    cls: str = ""
    routes: dict[str, int] = field(default_factory=dict)
    described: bool = False
    """Its ``@schema`` answer arrived."""


@dataclass
class Catalog:
    modules: dict[tuple[str, str], ModuleInfo] = field(default_factory=dict)
    slots: dict[str, SlotInfo] = field(default_factory=dict)
    slot_numbers: dict[str, dict[int, str]] = field(default_factory=dict)
    """robot → slot number → key."""

    @property
    def robots(self) -> list[str]:
        return sorted({r for r, _ in self.modules})

    def info(self, key: str) -> SlotInfo:
        """What is known about ``key``: a discovered slot, a bookkeeping key, or an unknown key."""
        known = self.slots.get(key)
        if known is not None:
            return known
        typ = bookkeeping_type(key)
        if typ is not None:
            return self.slots.setdefault(key, SlotInfo(key, type_name(typ), json_schema(typ), writers=["(bus)"]))
        return self.slots.setdefault(key, SlotInfo(key))

    def find(self, selection: str) -> list[SlotInfo]:
        """Slots whose key intersects the key expression ``selection``."""
        ke = zenoh.KeyExpr(selection)
        return [s for k, s in sorted(self.slots.items()) if ke.intersects(zenoh.KeyExpr(k))]


# ---------------------------------------------------------------- types

@functools.cache
def struct_type(name: str) -> type[msgspec.Struct] | None:
    """The struct class named ``package.module:Class`` when this installation has it, else None."""
    if not name:
        return None
    try:
        return resolve_type(name)
    except LookupError:
        return None


def bookkeeping_type(key: str) -> type[msgspec.Struct] | None:
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != keys.ROOT:
        return None
    if parts[1] == "@gcs":
        return gri.GcsHeartbeat if len(parts) == 4 and parts[3] == "heartbeat" else None
    if len(parts) == 4 and parts[2] == "@ral":
        return {gri.STATE: gri.GriState, gri.EVENTS: gri.GriEvent}.get(parts[3])
    if len(parts) == 4 and parts[2] == "@manager" and parts[3] == mri.STATE:
        return mri.RobotState
    if len(parts) == 4 and parts[3] == "@route":
        return RouteAck
    if len(parts) == 4 and parts[3] == "@heartbeat":
        return Heartbeat
    return None


def type_from_encoding(encoding: object) -> str:
    """The struct type named by a sample's encoding ``application/msgpack;<package.module:Class>`` ("" if none)."""
    text = str(encoding or "")
    head, sep, schema = text.partition(";")
    return schema if sep and head == ENCODING_PREFIX and ":" in schema else ""


class Decoder:
    """Decodes one key's payloads: through its struct when known (validating), else as plain msgpack."""

    __slots__ = ("type", "_typed")

    def __init__(self, type_name_: str) -> None:
        self.type = struct_type(type_name_)
        self._typed = msgspec.msgpack.Decoder(self.type).decode if self.type is not None else None

    def decode(self, payload: bytes) -> tuple[Any, str]:
        """``(value, problem)``: the value as builtins (structs as dicts); ``problem`` says why it did not
        validate against the struct ("" when it did, or when there is no struct to check)."""
        if self._typed is not None:
            try:
                return msgspec.to_builtins(self._typed(payload)), ""
            except msgspec.ValidationError as exc:
                problem = f"does not validate: {exc}"
            except msgspec.DecodeError as exc:
                raise ValueError(f"not msgpack: {exc}") from None
        else:
            problem = ""
        try:
            return msgspec.to_builtins(msgspec.msgpack.decode(payload)), problem
        except msgspec.DecodeError as exc:
            raise ValueError(f"not msgpack: {exc}") from None


# ---------------------------------------------------------------- discovery

def alive_modules(session: zenoh.Session, robot: str, timeout_s: float) -> list[tuple[str, str]]:
    found = set()
    for reply in session.liveliness().get(keys.alive_pattern(robot), timeout=timeout_s):
        if reply.ok is not None:
            try:
                found.add(keys.parse_alive_key(str(reply.ok.key_expr)))
            except Exception:
                continue
    return sorted(found)


def module_schema(session: zenoh.Session, robot: str, module: str, timeout_s: float) -> dict[str, Any] | None:
    """The module's ``@schema`` document (reply on its own key or on the query's key: both are accepted)."""
    for reply in session.get(keys.schema_key(robot, module), timeout=timeout_s):
        if reply.ok is None:
            continue
        try:
            doc = json.loads(reply.ok.payload.to_bytes())
        except ValueError:
            continue
        if isinstance(doc, dict) and doc.get("module", module) == module:
            return doc
    return None


def _slot_table(session: zenoh.Session, robot: str, timeout_s: float) -> dict[int, str]:
    try:
        reply = mri.call(session, robot, "routes", mri.ListRoutes(), timeout_s)
    except mri.MriError:
        return {}
    if not reply.ok or not isinstance(reply.data, mri.RouteList):
        return {}
    table = {}
    for number, where in reply.data.slots.items():
        module, _, slot = where.partition("/")
        try:
            table[int(number)] = keys.slot_key(robot, module, slot)
        except Exception:
            continue
    return table


def discover(session: zenoh.Session, robot: str = "*", timeout_s: float = 3.0) -> Catalog:
    """Ask the bus what runs on ``robot`` (``*``: every robot behind the router)."""
    cat = Catalog()
    alive = alive_modules(session, robot, timeout_s)
    for r, m in alive:
        cat.modules[(r, m)] = ModuleInfo(r, m)
    for r in sorted({r for r, _ in alive}):
        cat.slot_numbers[r] = _slot_table(session, r, timeout_s)
    docs = {}
    for r, m in alive:
        doc = module_schema(session, r, m, timeout_s)
        if doc is not None:
            docs[(r, m)] = doc
    for (r, m), doc in docs.items():
        _add_module(cat, r, m, doc)
    for table in cat.slot_numbers.values():
        for number, key in table.items():
            cat.slots.setdefault(key, SlotInfo(key)).number = number
    for key, entry in cat.slots.items():
        if not entry.writers and _manager_writes(key, docs):
            entry.writers.append("(manager)")
    for r, m in alive:
        cat.info(keys.route_ack_key(r, m))
        cat.info(keys.heartbeat_key(r, m))
        if m == "ral":
            cat.info(gri.state_key(r))
            cat.info(gri.events_key(r))
    for r in cat.slot_numbers:
        cat.info(keys.manager_key(r, mri.STATE))
    return cat


def _manager_writes(key: str, docs: dict[tuple[str, str], dict[str, Any]]) -> bool:
    """The manager writes its mode slots (``cromat/<r>/manager/<slot>``) and every CONTROL_ENTRADA."""
    _, robot, module, slot = key.split("/")
    control = (docs.get((robot, module)) or {}).get("control") or {}
    return module == "manager" or slot == control.get("slot")


def _add_module(cat: Catalog, robot: str, module: str, doc: dict[str, Any]) -> None:
    info = cat.modules[(robot, module)]
    info.described = True
    info.cls = str(doc.get("class", ""))
    info.routes = {str(k): int(v) for k, v in (doc.get("routes") or {}).items()}
    table = cat.slot_numbers.get(robot, {})
    for name, slot in (doc.get("slots") or {}).items():
        direction = slot.get("direction")
        peer = slot.get("peer")
        if peer:
            pm, _, ps = str(peer).partition("/")
            key = keys.slot_key(robot, pm, ps or name)
        elif direction == "in" and name in info.routes:
            number = info.routes[name]
            key = table.get(number, "")
            if not key:
                continue  # ignored (-1) or a number the manager did not name
        else:
            key = keys.slot_key(robot, module, name)
        entry = cat.slots.setdefault(key, SlotInfo(key))
        if not entry.type or direction == "out":
            entry.type = str(slot.get("type", ""))
            entry.schema = slot.get("schema") or {}
        if direction == "out" or not entry.kind:
            entry.kind, entry.safety = str(slot.get("kind", "")), str(slot.get("safety", ""))
        if direction == "out":
            entry.writers.append(module)
        else:
            routed = f"#{info.routes[name]}" if name in info.routes else ""
            entry.readers.append(f"{module}.{name}{routed}")
