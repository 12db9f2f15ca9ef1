"""Rates of keys on the bus: messages/s, interval jitter and bytes/s over a sliding window (pure, clock given)."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True)
class Rate:
    count: int
    """Messages in the window."""
    hz: float
    mean_interval_s: float
    jitter_s: float
    """Standard deviation of the intervals between messages."""
    min_interval_s: float
    max_interval_s: float
    bytes_per_s: float


class RateMeter:
    """Arrival times and sizes of one key's messages, the last ``window_s`` seconds of them."""

    def __init__(self, window_s: float = 5.0) -> None:
        self.window_s = window_s
        self._events: deque[tuple[float, int]] = deque()
        self.total = 0
        self.total_bytes = 0

    def add(self, t: float, size: int) -> None:
        self._events.append((t, size))
        self.total += 1
        self.total_bytes += size
        self._trim(t)

    def _trim(self, now: float) -> None:
        while self._events and self._events[0][0] < now - self.window_s:
            self._events.popleft()

    def rate(self, now: float) -> Rate:
        self._trim(now)
        times = [t for t, _ in self._events]
        size = sum(s for _, s in self._events)
        if len(times) < 2:
            return Rate(len(times), 0.0, 0.0, 0.0, 0.0, 0.0, size / self.window_s)
        intervals = [b - a for a, b in zip(times, times[1:], strict=False)]
        mean = sum(intervals) / len(intervals)
        var = sum((x - mean) ** 2 for x in intervals) / len(intervals)
        span = max(times[-1] - times[0], 1e-9)
        return Rate(len(times), (len(times) - 1) / span, mean, math.sqrt(var), min(intervals), max(intervals),
                    size / max(span, now - times[0], 1e-9))
