"""The aircraft the logger flies on and their MTi-G GPS lever arms (seed Table 12)."""

from __future__ import annotations

VEHICLES: dict[str, tuple[float, float, float]] = {
    "PILATUS_PORTER": (-0.45, -0.04, 0.0),
    "CB5000": (-0.34, 0.01, 0.26),
}
"""GPS antenna relative to the MTi-G in its body frame, metres."""


def vehicle_key(name: str) -> str:
    """Canonical vehicle name (``cb5000``, ``Pilatus Porter`` ...); ValueError for an unknown one."""
    key = name.strip().upper().replace("-", "_").replace(" ", "_")
    if key not in VEHICLES:
        raise ValueError(f"unknown vehicle {name!r}; known: {', '.join(sorted(VEHICLES))}")
    return key
