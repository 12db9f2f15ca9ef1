"""How many publishers and subscribers a key has, as ``ros2 topic info`` tells, from the router's admin space.

Zenoh tells a publisher only *whether* someone matches it; the router alone knows every declaration, and says so
in its admin space (``@/<zid>/router/subscriber/<key expr>``, ``.../publisher/<key expr>``: the sessions that
declared it) when the manifest turns that on (``[bus] admin_space = true``, off on the shipped manifests). A
declaration on a key expression counts for every key it intersects (a recorder's ``cromat/uav1/*/*`` reads every
slot), each session once. Without the admin space the counts are unknown (None), never guessed.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import zenoh

ADMIN = "@/*/router/{what}/**"


@dataclass
class Declarations:
    """Key expression → the sessions (Zenoh ids) that declared a subscriber or a publisher on it."""

    subscribers: dict[str, set[str]] = field(default_factory=dict)
    publishers: dict[str, set[str]] = field(default_factory=dict)

    def count(self, key: str) -> tuple[int, int]:
        """(publishers, subscribers) of ``key``: the distinct sessions whose declarations intersect it."""
        return _count(self.publishers, key), _count(self.subscribers, key)


def _count(table: dict[str, set[str]], key: str) -> int:
    target = zenoh.KeyExpr(key)
    who: set[str] = set()
    for expr, sessions in table.items():
        try:
            if zenoh.KeyExpr(expr).intersects(target):
                who |= sessions
        except Exception:  # noqa: BLE001 (an admin key that is no key expression: not a declaration)
            continue
    return len(who)


def parse_entry(admin_key: str, payload: bytes) -> tuple[str, str, set[str]] | None:
    """``("subscriber" | "publisher", key expr, sessions)`` of one admin-space reply, or None. The router's own
    id (the reply's ``@/<zid>/``) is left out: it relays, it does not consume."""
    parts = admin_key.split("/", 4)
    if len(parts) < 5 or parts[0] != "@" or parts[2] != "router" or parts[3] not in ("subscriber", "publisher"):
        return None
    try:
        doc = json.loads(payload)
    except ValueError:
        return None
    if not isinstance(doc, dict):
        return None
    sessions = {str(z) for kind in ("clients", "peers", "routers") for z in doc.get(kind) or []}
    return parts[3], parts[4], sessions - {parts[1]}


def declarations(session: zenoh.Session, timeout_s: float) -> Declarations | None:
    """What the router says is declared, or None when it does not answer (its admin space is off)."""
    if not any(reply.ok is not None for reply in session.get("@/*/router", timeout=timeout_s)):
        return None
    found = Declarations()
    for what in ("subscriber", "publisher"):
        for reply in session.get(ADMIN.format(what=what), timeout=timeout_s):
            if reply.ok is None:
                continue
            entry = parse_entry(str(reply.ok.key_expr), reply.ok.payload.to_bytes())
            if entry is not None:
                table = found.subscribers if entry[0] == "subscriber" else found.publishers
                table.setdefault(entry[1], set()).update(entry[2])
    return found
