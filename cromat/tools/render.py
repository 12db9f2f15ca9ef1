"""Plain-text and DOT renderings of decoded data and of the bus graph (pure functions)."""

from __future__ import annotations

import json
from typing import Any

from bbcs import keys
from cromat.tools.catalog import Catalog

LONG_TEXT = 200
"""Longer strings (packed arrays such as a lidar scan's points, base64) are cut in the human-readable echo."""


def yamlish(value: Any, indent: int = 0) -> list[str]:
    """A decoded datum as indented ``field: value`` lines, the way ``ros2 topic echo`` shows messages."""
    pad = "  " * indent
    if isinstance(value, dict):
        lines = []
        for k, v in value.items():
            if isinstance(v, dict) and v or isinstance(v, list) and v and isinstance(v[0], dict | list):
                lines.append(f"{pad}{k}:")
                lines.extend(yamlish(v, indent + 1))
            else:
                lines.append(f"{pad}{k}: {scalar(v)}")
        return lines
    if isinstance(value, list):
        lines = []
        for item in value:
            sub = yamlish(item, indent + 1)
            lines.append(f"{pad}- {sub[0].strip()}" if sub else f"{pad}-")
            lines.extend(sub[1:])
        return lines
    return [pad + scalar(value)]


def scalar(v: Any) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, str) and len(v) > LONG_TEXT:  # a packed array (bytes as base64): as ros2 topic echo does
        return f"{json.dumps(v[:48])[:-1]}…\" ({len(v)} chars; --json prints it whole)"
    if isinstance(v, str):
        return v if v and v.strip() == v and v[0] not in "-{[\"'" else json.dumps(v)
    if isinstance(v, list | dict):
        return json.dumps(v)
    return str(v)


def _short(key: str) -> str:
    return key.split("/", 1)[1] if key.startswith(keys.ROOT + "/") else key


def graph_text(cat: Catalog) -> list[str]:
    """Modules, then every slot as ``writers --> [number] key (Type) --> readers``."""
    lines = []
    for robot in cat.robots:
        mods = [m for (r, _), m in sorted(cat.modules.items()) if r == robot]
        lines.append(f"robot {robot}: {len(mods)} modules")
        for m in mods:
            routes = " ".join(f"{k}=" + (f"#{v}" if v >= 0 else "ignored") for k, v in sorted(m.routes.items())) or "-"
            lines.append(f"  {m.name:<14} {m.cls or '(no @schema answer)'}  routes {routes}")
        lines.append("  slots (writer --> [number] slot (type) --> reader.input#route):")
        prefix = f"{keys.ROOT}/{robot}/"  # a prefix to match keys the catalog saw, not a key to publish on
        for key, s in sorted(cat.slots.items()):
            if not key.startswith(prefix) or "@" in key or not (s.writers or s.readers):
                continue
            number = f"[{s.number}] " if s.number is not None else ""
            lines.append(f"    {','.join(s.writers) or '-':<14} --> {number}{_short(key)} ({s.short_type})"
                         f" --> {', '.join(s.readers) or '-'}")
    return lines


def _q(text: str) -> str:
    return json.dumps(text)


def graph_dot(cat: Catalog) -> str:
    """Graphviz DOT: modules as boxes, slots as ellipses, writer → slot → reader edges labelled by input."""
    out = ["digraph cromat {", "  rankdir=LR;", "  node [fontname=Helvetica fontsize=10];"]
    for robot, name in sorted(cat.modules):
        label = _q(name + "\n(" + robot + ")")
        out.append(f"  {_q(robot + '/' + name)} [shape=box style=filled fillcolor=lightblue label={label}];")
    for key, s in sorted(cat.slots.items()):
        if "@" in key or not (s.writers or s.readers):
            continue
        robot = key.split("/")[1]
        number = f" [#{s.number}]" if s.number is not None else ""
        out.append(f"  {_q(key)} [shape=ellipse label={_q(_short(key) + number + chr(10) + s.short_type)}];")
        for w in s.writers:
            out.append(f"  {_q(f'{robot}/{w}')} -> {_q(key)};")
        for reader in s.readers:
            module, _, inp = reader.partition(".")
            out.append(f"  {_q(key)} -> {_q(f'{robot}/{module}')} [label={_q(inp)}];")
    out.append("}")
    return "\n".join(out)
