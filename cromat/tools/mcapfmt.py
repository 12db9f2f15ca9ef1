"""How cromat data sit in an MCAP file (shared by the recorder, the replayer and the Foxglove bridge).

One channel per bus key, topic = the key. Messages are **JSON** (``message_encoding = "json"``) with a
**JSON Schema** (``schema encoding = "jsonschema"``, ``$ref``s inlined), which Foxglove reads natively; the
bus carries msgpack, and the struct type in the channel metadata turns each JSON message back into exactly the
msgpack bytes that were on the bus (msgspec encodes a struct one way only), which is what ``cromat replay``
publishes.
"""

from __future__ import annotations

import copy
from typing import Any

META_KEY = "cromat.key"
META_TYPE = "cromat.type"
META_KIND = "cromat.kind"
META_SAFETY = "cromat.safety"
META_BUS_ENCODING = "cromat.bus_encoding"
MESSAGE_ENCODING = "json"
SCHEMA_ENCODING = "jsonschema"
PROFILE = "cromat"
META_BUS = "cromat.bus"
"""Metadata record of a recording: the ``@schema`` answers (``schemas``: key → document) and the managers'
``routes`` answers (``routes``: robot → RouteList) in force when it began."""


def inline_refs(schema: dict[str, Any]) -> dict[str, Any]:
    """msgspec's schema with every ``#/$defs/X`` reference replaced by X, for viewers that do not follow
    ``$ref``: the root struct once, no ``$defs`` left. Only a recursive struct (one that contains itself) keeps a
    ``$ref`` to itself, with its definition under ``$defs``."""
    defs = schema.get("$defs", {})
    recursive: set[str] = set()

    def walk(node: Any, expanding: tuple[str, ...]) -> Any:
        if isinstance(node, dict):
            ref = node.get("$ref")
            if isinstance(ref, str) and ref.startswith("#/$defs/") and ref[8:] in defs:
                name = ref[8:]
                if name in expanding:  # a struct inside itself: the reference stays
                    recursive.add(name)
                    return dict(node)
                rest = {k: walk(v, expanding) for k, v in node.items() if k not in ("$ref", "$defs")}
                return {**walk(defs[name], (*expanding, name)), **rest}
            return {k: walk(v, expanding) for k, v in node.items() if k != "$defs"}
        if isinstance(node, list):
            return [walk(v, expanding) for v in node]
        return node

    if not schema:
        return {}
    out = walk(copy.deepcopy(schema), ())
    if recursive:
        kept: dict[str, Any] = {}
        pending = sorted(recursive)
        while pending:  # each kept definition expanded too, keeping references to the recursive ones only
            name = pending.pop()
            if name not in kept:
                kept[name] = walk(defs[name], (name,))
                pending += [n for n in recursive if n not in kept]
        out["$defs"] = kept
    return out
