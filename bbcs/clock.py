"""The one clock of a robot: the wall clock on hardware, the simulation's time in a lockstep simulation.

Why one clock: every timer that judges the robot (heartbeats, the watchdog, acknowledgement retries, the task
judge, the failsafe) must measure the same time the aircraft flies in. On hardware that is the wall clock. In a
lockstep simulation (docs/simulation.md, "Lockstep") the simulator's stepper carries simulated time on the bus
(``SimTime`` on ``cromat/<robot>/@clock``) and each process's :class:`SimClock` holds the last value it was given:
simulated time stands still while the modules work, so a loaded machine gives the same flight, only slower.

A clock has two readings, as the ``time`` module does: ``monotonic()`` for intervals and ``time()`` for stamps
(seconds since 1970: a simulation's time starts at its ``epoch``, the wall time its stepper started). Waiting
for a simulated interval is done with ``wait_for``, which also returns when the condition's predicate turns true.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol, runtime_checkable

import msgspec

SIM_WAIT_POLL_S = 0.02
"""Wall seconds a simulated-time wait sleeps between two looks at the clock (the clock moves in steps)."""


class SimTime(msgspec.Struct, frozen=True, kw_only=True):
    """Simulated time as the stepper publishes it: step number, seconds since the simulation began, its epoch."""

    step: int
    t: float
    """Simulated seconds since the simulation began."""
    epoch: float
    """Wall time (s since 1970) of simulated time 0: ``time()`` of a simulated clock is ``epoch + t``."""


@runtime_checkable
class Clock(Protocol):
    """What every timer of the robot reads."""

    @property
    def simulated(self) -> bool: ...

    def monotonic(self) -> float: ...

    def time(self) -> float: ...

    def wait_for(self, cond: threading.Condition, predicate: Callable[[], object], timeout: float | None) -> bool:
        """With ``cond`` held: wait until ``predicate()`` or ``timeout`` seconds of this clock; the predicate."""
        ...

    def sleep(self, seconds: float) -> None: ...


class WallClock:
    """The host's clocks: ``time.monotonic`` and ``time.time`` (real operation)."""

    simulated = False

    def monotonic(self) -> float:
        return time.monotonic()

    def time(self) -> float:
        return time.time()

    def wait_for(self, cond: threading.Condition, predicate: Callable[[], object], timeout: float | None) -> bool:
        return bool(cond.wait_for(predicate, timeout))

    def sleep(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))


class SimClock:
    """Simulated time, moved forward only by ``advance`` (from the stepper's ``SimTime``); never backward.

    Before the first ``advance`` it reads 0 (``time()``: the epoch it was built with, the wall time by default).
    Waits measure simulated seconds: a wait for 0.25 s lasts until the simulation has moved 0.25 s on, however
    long that takes on the wall."""

    simulated = True

    def __init__(self, epoch: float | None = None, *, poll_s: float = SIM_WAIT_POLL_S) -> None:
        self._t = 0.0
        self._step = -1
        self._epoch = time.time() if epoch is None else epoch
        self._poll_s = poll_s
        self._moved = threading.Condition()

    @property
    def step(self) -> int:
        """The stepper's step number last applied (-1: none yet)."""
        return self._step

    def advance(self, now: SimTime) -> bool:
        """Apply the stepper's time; False (nothing changed) for a step already applied or an older one."""
        with self._moved:
            if now.step <= self._step or now.t < self._t:
                return False
            self._step, self._t, self._epoch = now.step, now.t, now.epoch
            self._moved.notify_all()
            return True

    def monotonic(self) -> float:
        return self._t

    def time(self) -> float:
        return self._epoch + self._t

    def wait_for(self, cond: threading.Condition, predicate: Callable[[], object], timeout: float | None) -> bool:
        if timeout is None:
            return bool(cond.wait_for(predicate))
        end = self._t + timeout
        while True:
            result = predicate()
            if result or self._t >= end:
                return bool(result)
            cond.wait(self._poll_s)

    def sleep(self, seconds: float) -> None:
        """Block until simulated time has moved ``seconds`` on."""
        end = self._t + seconds
        with self._moved:
            while self._t < end:
                self._moved.wait(self._poll_s)


WALL = WallClock()
"""The wall clock every process uses unless it runs in a lockstep simulation."""
