"""Safety first in a module's loop: bulk inputs wait while safety work is queued (issue 32, "priorities").

A module's loop takes local events (stop, route changes, ``call_soon``) and every safe input's data in arrival
order. An *unsafe* input (newest value only: perception, targets, positions) is bulk: when its turn in the queue
comes it is set aside here, and handled once nothing safe waits. One bulk input is still handled per cycle of the
loop, so a steady stream of safe work delays bulk inputs but never starves them.

Reordering is harmless for a bulk input: it keeps only its newest value and makes no promise of order relative to
other inputs. Each reader is set aside at most once (its newest value waits on the reader itself, not here).

Pure: no threads, no clock; the loop asks ``safe_waiting`` (its queue is not empty) between bulk items.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from typing import Generic, TypeVar

T = TypeVar("T")


class SafetyFirst(Generic[T]):
    """Bulk items set aside in arrival order, handed back between safe work (module docstring)."""

    __slots__ = ("_bulk",)

    def __init__(self) -> None:
        self._bulk: deque[T] = deque()

    def __len__(self) -> int:
        return len(self._bulk)

    def defer(self, item: T) -> None:
        """Set a bulk item aside until :meth:`take` hands it back."""
        self._bulk.append(item)

    def take(self, safe_waiting: Callable[[], bool]) -> Iterator[T]:
        """The bulk items to handle now: the oldest one always, then more while ``safe_waiting()`` is False and
        only those set aside before this call (one cycle's worth; what arrives meanwhile waits for the next)."""
        bulk = self._bulk
        n = len(bulk)
        while n and bulk:
            yield bulk.popleft()
            n -= 1
            if safe_waiting():
                return

    def drain(self) -> list[T]:
        """Everything set aside, oldest first (a route switch handles all of it before its switch point)."""
        out = list(self._bulk)
        self._bulk.clear()
        return out
