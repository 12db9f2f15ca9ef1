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


def inline_refs(schema: dict[str, Any]) -> dict[str, Any]:
    """msgspec's schema with every ``#/$defs/X`` reference replaced by X (viewers that do not follow ``$ref``)."""
    defs = schema.get("$defs", {})

    def walk(node: Any, depth: int) -> Any:
        if depth > 32:
            return {}
        if isinstance(node, dict):
            ref = node.get("$ref")
            if isinstance(ref, str) and ref.startswith("#/$defs/") and ref[8:] in defs:
                merged = {**walk(defs[ref[8:]], depth + 1), **{k: v for k, v in node.items() if k != "$ref"}}
                return merged
            return {k: walk(v, depth + 1) for k, v in node.items() if k != "$defs"}
        if isinstance(node, list):
            return [walk(v, depth + 1) for v in node]
        return node

    return walk(copy.deepcopy(schema), 0) if schema else {}
