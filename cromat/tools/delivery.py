"""Did the router deliver what a tool published? A second session of the same identity listens on the keys.

Zenoh's access policy drops a refused put silently: the publisher sees no error, so ``cromat bus pub`` and ``cromat
replay`` printed success when the router had dropped everything (issue 32 item 9). :class:`RouterEcho` opens a
second session with the same options (its own Zenoh id, so what it gets came back through the router, not from
the publishing session itself) and counts what arrives on each key.
"""

from __future__ import annotations

import argparse
import threading
import time
from collections import Counter

import zenoh

from cromat.tools.connection import connect


class RouterEcho:
    """Counts, per key, what the router delivers of ``keys`` to a second session of the tool's identity."""

    def __init__(self, args: argparse.Namespace, keys: list[str]) -> None:
        self.session = connect(args)
        self.got: Counter[str] = Counter()
        self._cond = threading.Condition()
        self._subs = [self.session.declare_subscriber(k, self._on) for k in dict.fromkeys(keys)]

    def _on(self, sample: zenoh.Sample) -> None:
        with self._cond:
            self.got[str(sample.key_expr)] += 1
            self._cond.notify_all()

    def wait(self, sent: dict[str, int], timeout_s: float) -> dict[str, int]:
        """Wait until every key got what was ``sent`` on it, at most ``timeout_s``; returns key → delivered."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            self._cond.wait_for(lambda: all(self.got[k] >= n for k, n in sent.items()),
                                max(0.0, deadline - time.monotonic()))
            return {k: self.got[k] for k in sent}

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        self.session.close()


def dropped_keys(sent: dict[str, int], delivered: dict[str, int]) -> list[str]:
    """The keys of which the router delivered nothing although something was sent: its policy drops them."""
    return sorted(k for k, n in sent.items() if n and not delivered.get(k))
