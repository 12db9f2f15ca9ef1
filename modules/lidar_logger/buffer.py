"""The seed's two-slot FIFO between the scan receiver and the log writer (ch. 4.2.1, Figure 40).

The receiver puts each new scan at ``next_msg``; the writer takes the oldest unwritten one at ``next_proc``
and holds it while writing. A slot being written is never overwritten and an unwritten scan is never
replaced: when both slots are busy the *incoming* scan is dropped and counted, so the log stays in arrival
order and the writer's lag is visible (``dropped``) instead of silently losing older data.
"""

from __future__ import annotations

import threading
from typing import Generic, TypeVar

T = TypeVar("T")

EMPTY, FULL, WRITING = 0, 1, 2


class TwoSlotBuffer(Generic[T]):
    def __init__(self) -> None:
        self._items: list[T | None] = [None, None]
        self._state = [EMPTY, EMPTY]
        self._next_msg = 0
        self._next_proc = 0
        self._cond = threading.Condition()
        self._closed = False
        self.accepted = 0
        self.dropped = 0
        self.refused_after_close = 0

    def put(self, item: T, wait_s: float = 0.0) -> bool:
        """Receiver side. False when the item was not stored (buffer full, or closed). ``wait_s`` > 0: wait that
        many wall seconds at most for the writer to free the slot before dropping (a lockstep simulation, where
        the simulation waits for the receiver instead of the receiver losing what the writer has not caught up
        with)."""
        with self._cond:
            if wait_s > 0:
                self._cond.wait_for(lambda: self._closed or self._state[self._next_msg] == EMPTY, wait_s)
            if self._closed:
                self.refused_after_close += 1
                return False
            i = self._next_msg
            if self._state[i] != EMPTY:
                self.dropped += 1
                return False
            self._items[i] = item
            self._state[i] = FULL
            self._next_msg = 1 - i
            self.accepted += 1
            self._cond.notify_all()
            return True

    def take(self, timeout: float) -> T | None:
        """Writer side: the oldest unwritten item, now marked as being written; None after ``timeout``."""
        with self._cond:
            i = self._next_proc
            if self._state[i] != FULL:
                self._cond.wait(timeout)
                if self._state[i] != FULL:
                    return None
            self._state[i] = WRITING
            return self._items[i]

    def release(self) -> None:
        """Writer side: the item from ``take`` is written; its slot is free again."""
        with self._cond:
            i = self._next_proc
            if self._state[i] != WRITING:
                raise RuntimeError("release() without a matching take()")
            self._items[i] = None
            self._state[i] = EMPTY
            self._next_proc = 1 - i
            self._cond.notify_all()

    def close(self) -> None:
        """Refuse further puts (used when stopping); items already in are still taken."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def unwritten(self) -> int:
        with self._cond:
            return sum(1 for s in self._state if s == FULL)
