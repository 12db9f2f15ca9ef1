"""The DSP process's command intake: bounded, per sender, never blocking, one counted report per window.

A module with the narrowest DSP rights (pan & tilt's three classes on its own key) flooded valid batches at
53-95 k/s: the process queued them without limit (327,457 in one run), reported each refused or flushed batch
separately until its error stream filled, blocked, missed its heartbeat and was killed (issue 32 item 1). Here:

* a sender whose commands are set-points (pan & tilt: angles, mode, target) is **coalesced**: a batch replaces its
  newest waiting batch of the same command classes, since only the newest set-point matters;
* at most ``bound`` batches wait per sender; one beyond is **dropped** (the path follower's waypoints are never
  silently reordered or merged: they are refused, counted, and reported naming the sender);
* a batch holding ABORT is never dropped nor coalesced: it empties every queue and goes first;
* what was coalesced or dropped is counted per sender and reported at most once per ``window_s`` (:meth:`due`),
  naming the sender, never once per batch;
* a set-point superseded while the line is busy is what coalescing is for, not a fault: pan & tilt follows
  targets at the vision rate (10 Hz), so a few a second are superseded whenever a path upload holds the line. Only
  ``flood_batches`` or more coalesced or refused in one window make a flood (any drop does): below that, the
  window's counts are forgotten (the totals keep them). A single superseded set-point once failed a campaign's
  path task ("module dsp reported error 106 FLOODED").

Pure: no threads, no clock of its own (``now`` is passed in); the process holds its lock around it.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

COALESCED_SENDERS = frozenset({"pan_tilt"})
"""Senders whose batches are set-points: the newest replaces a waiting one."""
DEFAULT_BOUND = 32
"""Batches waiting per sender: a few seconds of a normal sender's traffic (the DSP acknowledges ~100 commands/s)."""
REPORT_WINDOW_S = 1.0
FLOOD_BATCHES = 50
"""Batches of one sender coalesced or refused in one window that make a flood: 5x pan & tilt's vision rate,
a quarter of the rate the robot router lets through on its key (bbcs/acl.py ``SET_POINT_RATES_HZ``)."""


@dataclass
class Flood:
    """What one sender lost in one report window."""

    sender: str
    coalesced: int = 0
    dropped: int = 0
    refused: int = 0
    """Batches refused for a command class the sender does not own (NOT_OWNER), beyond the one reported at once."""
    since: float | None = None
    """When :meth:`CommandIntake.due` first saw this window's losses."""

    @property
    def total(self) -> int:
        return self.coalesced + self.dropped + self.refused


@dataclass
class _Sender:
    waiting: int = 0
    flood: Flood = field(default_factory=lambda: Flood(""))
    last_report: float = -float("inf")


class CommandIntake:
    """Batches waiting to be sent, in arrival order, at most ``bound`` per sender (module docstring)."""

    def __init__(self, bound: int = DEFAULT_BOUND, window_s: float = REPORT_WINDOW_S,
                 coalesced: frozenset[str] = COALESCED_SENDERS, flood_batches: int = FLOOD_BATCHES) -> None:
        self.bound = bound
        self.window_s = window_s
        self.flood_batches = flood_batches
        self.coalesced = coalesced
        self._queue: deque[tuple[str, tuple[str, ...], Any]] = deque()
        self._senders: dict[str, _Sender] = {}
        self.total_coalesced = 0
        self.total_dropped = 0

    def __len__(self) -> int:
        return len(self._queue)

    def _sender(self, name: str) -> _Sender:
        s = self._senders.get(name)
        if s is None:
            s = self._senders[name] = _Sender(flood=Flood(name))
        return s

    def offer(self, sender: str, batch: Any, kinds: tuple[str, ...] = (), *, abort: bool = False) -> list[Any]:
        """Queue ``batch`` (``kinds``: its command classes, in order); returns the batches it flushed (an ABORT
        flushes every waiting one and goes first). A coalesced sender's batch replaces its newest waiting batch of
        the same ``kinds`` (a newer set-point of the same things); past ``bound`` waiting, a batch is dropped."""
        s = self._sender(sender)
        if abort:
            flushed = [b for _, _, b in self._queue]
            self._queue.clear()
            for other in self._senders.values():
                other.waiting = 0
            self._queue.appendleft((sender, kinds, batch))
            s.waiting = 1
            return flushed
        if sender in self.coalesced and s.waiting:
            for i in range(len(self._queue) - 1, -1, -1):  # the sender's newest waiting batch
                if self._queue[i][0] == sender:
                    if self._queue[i][1] == kinds:
                        self._queue[i] = (sender, kinds, batch)
                        s.flood.coalesced += 1
                        self.total_coalesced += 1
                        return []
                    break
        if s.waiting >= self.bound:
            s.flood.dropped += 1
            self.total_dropped += 1
            return []
        self._queue.append((sender, kinds, batch))
        s.waiting += 1
        return []

    def refuse(self, sender: str, now: float) -> bool:
        """Count a batch refused for rights; True if it is the first of a window (report it in full now), False
        if it is only counted (:meth:`due` reports the count)."""
        s = self._sender(sender)
        if not s.flood.total and now - s.last_report >= self.window_s:
            s.last_report = now
            return True
        s.flood.refused += 1
        return False

    def take(self) -> tuple[str, Any] | None:
        """The next batch to send (oldest first, an ABORT before everything), or None."""
        if not self._queue:
            return None
        sender, _, batch = self._queue.popleft()
        self._senders[sender].waiting -= 1
        return sender, batch

    def is_flood(self, f: Flood) -> bool:
        """A drop always counts; coalesced and refused batches only from ``flood_batches`` on (module docstring)."""
        return f.dropped > 0 or f.coalesced + f.refused >= self.flood_batches

    def due(self, now: float) -> list[Flood]:
        """The senders flooding since their last report, if their report window has passed: each once. Losses
        below a flood are forgotten once they are a window old."""
        out = []
        for s in self._senders.values():
            f = s.flood
            if not f.total:
                continue
            if f.since is None:
                f.since = now
            if self.is_flood(f):
                if now - s.last_report >= self.window_s:
                    out.append(f)
                    s.flood = Flood(f.sender)
                    s.last_report = now
            elif now - f.since >= self.window_s:
                s.flood = Flood(f.sender)
        return out
