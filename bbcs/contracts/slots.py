"""Types the slot-routing contract shares across modules."""

from __future__ import annotations

from typing import Annotated

import msgspec

SlotNumber = Annotated[int, msgspec.Meta(ge=-1)]
"""A slot-table number; -1 means "ignore this input"."""
