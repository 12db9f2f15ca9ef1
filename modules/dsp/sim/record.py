"""Reading the DSP simulator's command record (``--record FILE``, one JSON object per line).

Why one reader: the record also holds link retransmissions the simulator recognised as duplicates (``duplicate``
true, no fields: the command was already applied once), and the simulator may be writing its last line while it
is read. Every consumer wants the commands the DSP applied, in order, and only whole lines.
"""

from __future__ import annotations

import json
import os
from typing import Any


def read_record(path: str | os.PathLike[str], *, duplicates: bool = False) -> list[dict[str, Any]]:
    """The commands applied so far, in order (``duplicates=True``: retransmissions too); [] before the file exists.

    A line still being written (no newline yet) is left for the next read."""
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except FileNotFoundError:
        return []
    rows = [json.loads(line) for line in text[: text.rfind("\n") + 1].splitlines() if line.strip()]
    return rows if duplicates else [r for r in rows if not r.get("duplicate")]
