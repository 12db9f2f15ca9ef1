"""Injected clocks, so every timeout and period can run faster than real time in tests and simulations.

All durations handed to a clock are in *clock seconds*. ``ScaledClock(10)`` runs ten times faster than the
wall clock: a 15 s timeout passes in 1.5 s, a 20 ms poll period sleeps 2 ms.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    def now(self) -> float:
        """Monotonic time in clock seconds."""
        ...

    def sleep(self, seconds: float) -> None:
        ...

    def wait(self, event: threading.Event, seconds: float) -> bool:
        """Wait for ``event`` at most ``seconds`` clock seconds; True if it was set."""
        ...

    def wall(self, seconds: float) -> float:
        """Wall-clock seconds that ``seconds`` clock seconds last."""
        ...


class SystemClock:
    """Real time (``time.monotonic``)."""

    scale = 1.0

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    def wait(self, event: threading.Event, seconds: float) -> bool:
        return event.wait(max(seconds, 0.0))

    def wall(self, seconds: float) -> float:
        return seconds


class ScaledClock:
    """Time running ``scale`` times faster than the wall clock, from 0 at creation (or ``start``)."""

    def __init__(self, scale: float, start: float = 0.0) -> None:
        if scale <= 0:
            raise ValueError(f"time scale must be positive, got {scale}")
        self.scale = float(scale)
        self._t0 = time.monotonic()
        self._start = start

    def now(self) -> float:
        return self._start + (time.monotonic() - self._t0) * self.scale

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds / self.scale)

    def wait(self, event: threading.Event, seconds: float) -> bool:
        return event.wait(max(seconds, 0.0) / self.scale)

    def wall(self, seconds: float) -> float:
        return seconds / self.scale


SYSTEM_CLOCK = SystemClock()
