"""The optional packages each tool needs (the ``tools`` extra), checked before a tool starts."""

from __future__ import annotations

import importlib.util

NEEDS: dict[str, tuple[str, ...]] = {
    "record": ("mcap",),
    "replay": ("mcap",),
    "foxglove": ("foxglove", "websockets"),
    "bag": ("mcap",),
}


def require(tool: str) -> str | None:
    """None when ``tool`` can run, else a message saying what to install."""
    missing = [m for m in NEEDS.get(tool, ()) if importlib.util.find_spec(m) is None]
    if not missing:
        return None
    return (f"cromat {tool}: needs {', '.join(missing)} (the tools extra): pip install 'cromat[tools]' "
            "or pip install -e '.[tools]' in a checkout")
