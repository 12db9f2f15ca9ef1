"""Floods named in the router's log: what its write-rate limits dropped, per identity and key, once a second.

The robot router limits some identities' writes per key (Zenoh's downsampling at its ingress, per link: bbcs/acl.py
``SET_POINT_RATES_HZ`` and the manifest's ``write_hz``). Zenoh drops what goes over silently, except for a TRACE line
of ``zenoh::net::routing::interceptor::downsampling`` per dropped message ("Message dropped by the downsampling
interceptor: Push(<key>) from:<region>/<zid prefix>:<n>"). With that target enabled, the router reads those lines
(bbcs/router_audit.py's pipe), counts them by sender and key, and prints at most one line per sender and key a
second, naming the sender by its certificate name when its link has one (``session.info.links()``):

    cromat router: flood: vision (3f2a9c1e) put 96,112 messages on cromat/uav1/vision/target over its write
    limit in 1.0 s: dropped here

Cost: one line per dropped message crosses the pipe, read in chunks and counted by one regular expression (no
Python per line). The pipe stays blocking: Zenoh's log writer reports a failed write on stderr, once per line, so
a non-blocking pipe would move the flood to stderr. Measured (a TLS flood of pan & tilt's DSP key, 120-470 k/s
from one Python process): the router spends 0.6 us per flooded message without these lines and 1.4-3.4 us with
them, about 20 % of a processor more while a flood is being dropped, nothing otherwise.
"""

from __future__ import annotations

import re
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import TextIO

LOG_TARGET = "zenoh::net::routing::interceptor::downsampling=trace"
_LINE = re.compile(rb"[^\n]*Message dropped by the downsampling interceptor: Push\(([^)]*)\) "
                   rb"from:(?:\S*/)?([0-9a-f]+)[^\n]*\n")
"""One such line (ANSI colours and all): its key and sender's zid prefix."""


class FloodLog:
    """Counts dropped messages per (sender, key); :meth:`due` gives each one line per ``period_s``."""

    def __init__(self, clock: Callable[[], float] = time.monotonic, period_s: float = 1.0) -> None:
        self.clock = clock
        self.period_s = period_s
        self.names: Callable[[], dict[str, str]] = dict
        """zid prefix → certificate name of the links the router holds (set once its session is open)."""
        self._counts: Counter[tuple[str, str]] = Counter()
        self._lock = threading.Lock()
        self._since = clock()
        self.total = 0

    def feed(self, data: bytes) -> bytes:
        """Count the downsampling drops among ``data``'s whole lines; the other lines, for the rest of the log.
        At C speed (one regex pass to count, one to cut): a flood writes one such line per dropped message."""
        found = _LINE.findall(data)
        if not found:
            return data
        counts = Counter(found)
        with self._lock:
            for (key, zid), n in counts.items():
                self._counts[(zid.decode(), key.decode())] += n
            self.total += len(found)
        return _LINE.sub(b"", data)

    def due(self) -> list[str]:
        """One line per sender and key with drops, if ``period_s`` has passed since the last lines."""
        now = self.clock()
        if now - self._since < self.period_s:
            return []
        with self._lock:
            counts, self._counts = self._counts, Counter()
        span, self._since = now - self._since, now
        names = self.names() if counts else {}
        out = []
        for (zid, key), n in sorted(counts.items()):
            who = next((cn for z, cn in names.items() if z.startswith(zid)), "")
            out.append(f"cromat router: flood: {who + ' (' + zid + ')' if who else zid} put {n:,} messages on {key} "
                       f"over its write limit in {span:.1f} s: dropped here")
        return out


def link_names(session: object) -> Callable[[], dict[str, str]]:
    """zid → the certificate name (``auth_identifier``) of each link ``session`` (the router's own) holds."""
    def names() -> dict[str, str]:
        out = {}
        try:
            for link in session.info.links():  # type: ignore[attr-defined]
                ident = str(link.auth_identifier or "")
                out[str(link.zid)] = ident
        except Exception:  # the session is closing
            pass
        return out
    return names


def start_reporting(log: FloodLog, out: TextIO, stop: threading.Event) -> threading.Thread:
    """Print ``log``'s lines on ``out`` once a second until ``stop``."""
    def run() -> None:
        while not stop.wait(log.period_s):
            lines = log.due()
            if lines:
                out.write("".join(line + "\n" for line in lines))
                out.flush()

    thread = threading.Thread(target=run, name="router-floods", daemon=True)
    thread.start()
    return thread
