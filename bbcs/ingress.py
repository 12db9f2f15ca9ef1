"""Ingress guards on what a module receives, for what Zenoh's access policy cannot tell apart.

Zenoh's policy admits a put when an *allow* rule's key expression includes the put's, and refuses it when a *deny*
rule's includes it. A put on a key expression with wildcards (``cromat/uav1/pan_tilt/*``) is included in the
module's own allow (``cromat/uav1/pan_tilt/*``) and in no deny of a single key (``…/pan_tilt/control_entrada``),
yet Zenoh delivers it to every subscriber whose key it intersects, that denied key included (issue 32 item 6). An
input that only one writer may feed, and that a wider allow of another identity covers (CONTROL_ENTRADA: the
manager's, under the module's own ``<module>/*``; the DSP's command inputs under the DSP's ``dsp/*``), therefore
takes only samples put on its exact key: anything else is dropped and counted, and reported at most once a window
(never once per datum), so a flood of them cannot flood the ERROR slot.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

REPORT_WINDOW_S = 1.0
"""At most one report per guard per this many seconds; the report carries the count since the last one."""


class ExactKeyGuard:
    """Passes on samples put on ``key`` itself; drops the rest (a wildcard put that intersects it), counted.

    ``report(count, example_key)`` is called on the receiving thread at most once per ``window_s`` with the number
    dropped since the previous report and one key expression that was refused."""

    def __init__(self, key: str, report: Callable[[int, str], None], *, window_s: float = REPORT_WINDOW_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.key = key
        self.refused = 0
        """Samples dropped since the guard was made."""
        self._report = report
        self._window_s = window_s
        self._clock = clock
        self._unreported = 0
        self._last_report = -float("inf")
        self._lock = threading.Lock()

    def admits(self, sample_key: str) -> bool:
        """Whether a sample delivered on ``sample_key`` may be handled; counts and maybe reports a refusal."""
        if sample_key == self.key:
            return True
        with self._lock:
            self.refused += 1
            self._unreported += 1
            now = self._clock()
            if now - self._last_report < self._window_s:
                return False
            count, self._unreported, self._last_report = self._unreported, 0, now
        self._report(count, sample_key)
        return False

    def wrap(self, callback: Callable[[Any], None]) -> Callable[[Any], None]:
        """``callback`` behind this guard (a Zenoh subscriber callback)."""
        admits = self.admits

        def guarded(sample: Any) -> None:
            if admits(str(sample.key_expr)):
                callback(sample)
        return guarded
