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


class RobotClock:
    """A robot's ``bbcs.clock.Clock`` (a lockstep simulation's ``SimClock``) as the logger's ``Clock``: simulated
    seconds that stand still while the simulation waits. ``wall`` cannot know how long simulated seconds last on
    the wall, so it answers a short poll (the waits here look at the clock again after it)."""

    scale = 1.0
    POLL_S = 0.02

    def __init__(self, clock) -> None:  # bbcs.clock.Clock (not imported: this module stays free of the bus)
        self._clock = clock

    def now(self) -> float:
        return self._clock.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self._clock.sleep(seconds)

    def wait(self, event: threading.Event, seconds: float) -> bool:
        end = self.now() + max(seconds, 0.0)
        while not event.is_set():
            if self.now() >= end:
                return False
            event.wait(self.POLL_S)
        return True

    def wall(self, seconds: float) -> float:
        return min(max(seconds, 0.0), self.POLL_S)


SYSTEM_CLOCK = SystemClock()
