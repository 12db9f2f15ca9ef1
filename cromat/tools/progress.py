"""One status line for long-running commands: rewritten in place on a terminal, silent when piped."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class StatusLine:
    def __init__(self, stream: TextIO | None = None, *, period_s: float = 0.25, force: bool | None = None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = self.stream.isatty() if force is None else force
        self.period_s = period_s
        self._last = 0.0
        self._width = 0

    def show(self, text: str, *, now: float | None = None, force: bool = False) -> None:
        if not self.enabled:
            return
        t = time.monotonic() if now is None else now
        if not force and t - self._last < self.period_s:
            return
        self._last = t
        text = text[:119]
        self.stream.write("\r" + text.ljust(self._width))
        self._width = len(text)
        self.stream.flush()

    def done(self) -> None:
        if self.enabled and self._width:
            self.stream.write("\r" + " " * self._width + "\r")
            self.stream.flush()
            self._width = 0


def bar(fraction: float, width: int = 30) -> str:
    """``[#######-------]`` for a fraction in 0..1."""
    filled = max(0, min(width, round(fraction * width)))
    return "[" + "#" * filled + "-" * (width - filled) + "]"
