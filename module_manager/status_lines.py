"""Status lines on stdout, whole: whoever reads them (a fleet launcher, a test, a log shipper) matches lines by
their start, and several threads print them.

``print()`` writes the text and the newline in two calls, so two threads printing at once can glue one line onto
the end of another ("[uav3] …fleet: all 10 robots up"), and a reader waiting for that line never sees it. Here a
line and its newline go out in one write under one lock.
"""

from __future__ import annotations

import os
import sys
import threading

_lock = threading.Lock()
_gone = False


def print_line(line: str) -> None:
    """Print one whole line and flush it; once whoever read our stdout has gone (a closed pipe), stay quiet instead
    of failing: a shutdown interrupted by a BrokenPipeError would leave modules running and sessions open."""
    global _gone
    with _lock:
        if _gone:
            return
        try:
            sys.stdout.write(line + "\n")
            sys.stdout.flush()
        except (BrokenPipeError, ValueError, OSError):
            _gone = True
            try:  # nothing left to flush into the closed pipe at exit either
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            except (OSError, ValueError):
                pass
