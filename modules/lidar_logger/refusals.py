"""Coalesced reports of refused device data (damaged frames, cut scans): pure, with the caller's clock.

A device link that goes bad refuses frames by the hundred; one error report each would flood the module's ERROR
slot (every code is sent, in order) while saying nothing more than the first. So the first refusal is reported
at once, and the later ones are counted and reported together at most once per ``period_s``, with how many, over
how long and the last reason. :meth:`Refusals.poll` (called from the link's loop) reports a count left pending.
"""

from __future__ import annotations

from dataclasses import dataclass

REPORT_PERIOD_S = 1.0


@dataclass
class Refusals:
    what: str
    """The link's name in every report (``LD-MRS``, ``MTi-G``)."""
    period_s: float = REPORT_PERIOD_S
    total: int = 0
    """Every refusal so far."""
    reports: int = 0
    """Reports made (each covers one or more refusals)."""
    _pending: int = 0
    _pending_since: float = 0.0
    _last_reason: str = ""
    _last_report: float | None = None

    def note(self, now: float, reason: str, count: int = 1) -> str | None:
        """``count`` more refusals for ``reason``; the report to make now, or None (counted for a later one)."""
        if count <= 0:
            return None
        self.total += count
        if self._pending == 0:
            self._pending_since = now
        self._pending += count
        self._last_reason = reason
        return self.poll(now)

    def poll(self, now: float) -> str | None:
        """The report of the refusals still pending once ``period_s`` has passed since the last report."""
        if not self._pending:
            return None
        if self._last_report is not None and now - self._last_report < self.period_s:
            return None
        if self._pending == 1:
            text = f"{self.what}: {self._last_reason} ({self.total} refused so far)"
        else:
            span = max(0.0, now - self._pending_since)
            text = (f"{self.what}: {self._pending} refused in the last {span:.1f} s ({self.total} so far); "
                    f"the last: {self._last_reason}")
        self._pending = 0
        self._last_report = now
        self.reports += 1
        return text
