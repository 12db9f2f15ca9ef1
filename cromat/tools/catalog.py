"""What is on a robot's bus: every slot's key, struct type, JSON Schema, writer, readers and routes.

Learned from the bus itself, in one round of queries: liveliness tokens name the modules alive; one wildcard get
on ``cromat/<robot>/*/@schema`` returns every module's description (slots, routes, and its ``@route`` /
``@heartbeat`` keys), and ``@manager/@schema`` / ``@ral/@schema`` describe the manager's and the RAL's keys; the
manager's ``routes`` answer turns slot numbers into names. A key nobody describes is typed by its samples'
encoding (``application/msgpack;<package.module:Class>``), else decoded as plain msgpack.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from typing import Any

import msgspec
import zenoh

from bbcs import keys
from bbcs.codec import resolve_type
from bbcs.contracts import mri
from bbcs.session import SessionConfig, alive_everywhere
from bbcs.wire import MSGPACK as ENCODING_PREFIX


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
    docs: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Every ``@schema`` answer as it came, by its key (a recording keeps them so its replay can answer them)."""
    route_lists: dict[str, mri.RouteList] = field(default_factory=dict)
    """robot → the manager's ``routes`` answer, as it came."""

    @property
    def robots(self) -> list[str]:
        return sorted({r for r, _ in self.modules})

    def info(self, key: str, encoding: object = "") -> SlotInfo:
        """What is known about ``key``: a described slot or key; else, once a sample's ``encoding`` names its
        struct, that type (and its schema when this installation has the struct)."""
        known = self.slots.get(key)
        if known is None:
            known = self.slots.setdefault(key, SlotInfo(key))
        if not known.type and (tname := type_from_encoding(encoding)):
            typ = struct_type(tname)
            known.type, known.schema = tname, msgspec.json.schema(typ) if typ is not None else {}
        return known

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


@functools.cache
def stand_in(name: str) -> type[msgspec.Struct]:
    """A field-less struct *named* ``package.module:Class``, the slot type of a publisher of bytes whose struct
    is not installed here: what goes on the wire then says the real type (``application/msgpack;<name>``)."""
    module, _, qualname = name.partition(":")
    return msgspec.defstruct(qualname or "Unknown", [], module=module or __name__)


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

def alive_modules(session: zenoh.Session, robot: str, timeout_s: float,
                  config: SessionConfig | None = None) -> list[tuple[str, str]]:
    """(robot, module) of every liveliness token behind the router, or behind each router ``config`` names."""
    found = set()
    for key in alive_everywhere(session, config or SessionConfig(), keys.alive_pattern(robot), timeout_s):
        try:
            found.add(keys.parse_alive_key(key))
        except Exception:
            continue
    return sorted(found)


def _schema_docs(session: zenoh.Session, selector: str, timeout_s: float) -> dict[str, dict[str, Any]]:
    """``@schema`` key → its JSON document, for every queryable that answers ``selector`` (each replies on
    its own key)."""
    docs = {}
    for reply in session.get(selector, timeout=timeout_s):
        if reply.ok is None:
            continue
        try:
            doc = json.loads(reply.ok.payload.to_bytes())
        except ValueError:
            continue
        if isinstance(doc, dict):
            docs[str(reply.ok.key_expr)] = doc
    return docs


def _slot_table(session: zenoh.Session, robot: str, timeout_s: float, cat: Catalog) -> dict[int, str]:
    try:
        reply = mri.call(session, robot, "routes", mri.ListRoutes(), timeout_s)
    except mri.MriError:
        return {}
    if not reply.ok or not isinstance(reply.data, mri.RouteList):
        return {}
    cat.route_lists[robot] = reply.data
    table = {}
    for number, where in reply.data.slots.items():
        module, _, slot = where.partition("/")
        try:
            table[int(number)] = keys.slot_key(robot, module, slot)
        except Exception:
            continue
    return table


def discover(session: zenoh.Session, robot: str = "*", timeout_s: float = 3.0,
             config: SessionConfig | None = None) -> Catalog:
    """Ask the bus what runs on ``robot`` (``*``: every robot behind the router, or behind each router ``config``
    names: the session's own configuration, given when it names several)."""
    cat = Catalog()
    alive = alive_modules(session, robot, timeout_s, config)
    for r, m in alive:
        cat.modules[(r, m)] = ModuleInfo(r, m)
    for r in sorted({r for r, _ in alive}):
        cat.slot_numbers[r] = _slot_table(session, r, timeout_s, cat)
    docs: dict[tuple[str, str], dict[str, Any]] = {}
    for key, doc in _schema_docs(session, keys.schema_pattern(robot), timeout_s).items():
        cat.docs[key] = doc
        r, m = key.split("/")[1:3]
        if (r, m) in cat.modules:
            docs[(r, m)] = doc
    for (r, m), doc in docs.items():
        _add_module(cat, r, m, doc)
    for table in cat.slot_numbers.values():
        for number, key in table.items():
            cat.slots.setdefault(key, SlotInfo(key)).number = number
    for key, entry in cat.slots.items():
        if not entry.writers and _manager_writes(key, docs):
            entry.writers.append("(manager)")
    for service in (keys.manager_key(robot), keys.ral_key(robot)):
        for key, doc in _schema_docs(session, keys.schema_key_of(service), timeout_s).items():
            cat.docs[key] = doc
            writer = f"({key.split('/')[2].lstrip('@')})"
            _add_keys(cat, doc, writer)
    for doc in docs.values():
        _add_keys(cat, doc.get("keys") or {}, "(bus)")
    return cat


def _add_keys(cat: Catalog, described: dict[str, Any], writer: str) -> None:
    """Keys a service or module publishes besides its slots (``{key: {"type", "schema"}}``); queryables
    (``{"request", "reply"}``) are answered, not published, and are left out."""
    for key, entry in described.items():
        if not isinstance(entry, dict) or "type" not in entry:
            continue
        info = cat.slots.setdefault(key, SlotInfo(key))
        info.type, info.schema = str(entry["type"]), entry.get("schema") or {}
        if writer not in info.writers:
            info.writers.append(writer)


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
