"""Refused telemetry frames: counted one by one, reported in bounded number (pure, the clock passed in).

A telemetry frame that passed the CRC but does not decode, or has a field outside the range its type declares
(bbcs/contracts/dsp.py), is dropped by the link. One such frame is a line fault the CRC let through: the operator
must see it, but it says nothing about the aircraft. A run of them (a broken GPS giving latitude 200° in every
frame, a flood from a faulty line) must not become one report per frame: the DSP process's ERROR slot is a safe
slot, every code queued and delivered, so 50 frames a second would bury every other error.

The rule: the first refused frame after a quiet period is reported at once; the ones after it are counted and
reported together once ``period_s`` has passed since the previous report (on the next refusal or the next
``flush``). So a single bad frame gives exactly one report, and any flood at most one report per ``period_s``
plus one, while every frame is still counted exactly (``total``, and ``frames`` per report).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

REPORT_PERIOD_S = 1.0
"""At most one report of refused telemetry per second (docs/dsp_protocol.md §5.4)."""


@dataclass(frozen=True)
class Refusal:
    """One refused telemetry frame: the field that failed (``position.lat``; ``frame`` when the payload did not
    decode at all) and why, naming value and range."""

    field: str
    detail: str


@dataclass(frozen=True)
class RefusalReport:
    """What one report says: the frames refused since the previous report, by field, and the running total."""

    frames: int
    total: int
    by_field: tuple[tuple[str, int], ...]
    last: str
    window_s: float

    def text(self) -> str:
        fields = ", ".join(f"{name} {n}" for name, n in self.by_field)
        span = f" in {self.window_s:.1f} s" if self.frames > 1 else ""
        return (f"{self.frames} telemetry frame{'s' if self.frames > 1 else ''} refused{span} ({fields}), "
                f"{self.total} since the link opened; last: {self.last}")


@dataclass
class RefusalCounter:
    """Counts refused frames and decides when to report them (not thread-safe: its owner holds a lock)."""

    period_s: float = REPORT_PERIOD_S
    total: int = 0
    reports: int = 0
    _pending: Counter[str] = field(default_factory=Counter)
    _window_start: float | None = None
    _last_report: float | None = None
    _last: str = ""

    def __post_init__(self) -> None:
        if self.period_s <= 0:
            raise ValueError("period_s must be positive")

    @property
    def pending(self) -> int:
        """Frames refused since the last report, not reported yet."""
        return sum(self._pending.values())

    def refuse(self, refusal: Refusal, now: float) -> RefusalReport | None:
        """Count one refused frame; the report to make now, if one is due."""
        self.total += 1
        self._pending[refusal.field] += 1
        self._last = refusal.detail
        if self._window_start is None:
            self._window_start = now
        return self.flush(now)

    def flush(self, now: float) -> RefusalReport | None:
        """The report of the frames still pending, if ``period_s`` has passed since the previous report."""
        if not self._pending or (self._last_report is not None and now - self._last_report < self.period_s):
            return None
        start = self._window_start if self._window_start is not None else now
        report = RefusalReport(frames=self.pending, total=self.total, by_field=tuple(sorted(self._pending.items())),
                               last=self._last, window_s=max(0.0, now - start))
        self._pending.clear()
        self._window_start = None
        self._last_report = now
        self.reports += 1
        return report
