"""SIGINT/SIGTERM handled on a helper thread, never inside a signal handler.

Why: Python runs a signal handler on the main thread between two bytecodes, possibly while that thread holds a
lock. A handler that sets a ``threading.Event``, puts into a ``queue.Queue`` or calls anything that takes a lock
deadlocks when the signal lands inside that lock, or when a second signal lands inside the first handler. Measured
under load: a module's handler (``request_stop``) interrupted the module's own ``Event.set()`` at shutdown, and the
orphaned process hung for good; a router did the same. Here the Python-level handler does nothing: the C-level
handler writes the signal's number to a pipe (``signal.set_wakeup_fd``), and a daemon thread reading it calls the
callback, where taking locks is safe.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

__all__ = ["STOP_SIGNALS", "exit_deadline", "forward_stop_signals"]


def _noted(signum: int, frame: object) -> None:
    """The Python-level handler: nothing (the wakeup pipe carries the signal); not the default action, which
    would end the process."""


def forward_stop_signals(callback: Callable[[int], None]) -> Callable[[], None]:
    """From now on, each SIGINT or SIGTERM calls ``callback(signum)`` on a daemon thread. Call from the main
    thread (Python's rule for handlers); returns ``restore``, which puts back the previous handlers and wakeup fd
    (after it, a stop signal has its previous effect, by default the end of the process)."""
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    try:
        previous_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
        previous = {sig: signal.signal(sig, _noted) for sig in STOP_SIGNALS}
    except ValueError:
        os.close(read_fd)
        os.close(write_fd)
        raise

    def pump() -> None:
        while True:
            try:
                data = os.read(read_fd, 64)
            except OSError:
                return
            if not data:  # restore() closed the write end
                os.close(read_fd)
                return
            for signum in data:
                if signum in STOP_SIGNALS:
                    callback(signum)

    threading.Thread(target=pump, name="stop-signals", daemon=True).start()
    restored = False

    def restore() -> None:
        nonlocal restored
        if restored:
            return
        restored = True
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        signal.set_wakeup_fd(previous_fd)
        os.close(write_fd)

    return restore


def exit_deadline(seconds: int) -> None:
    """A stopping process's last resort: SIGALRM, left to its default action, ends it ``seconds`` from now,
    whatever Python is doing then (an interpreter's exit runs no Python thread that could help). Measured under
    load: orphaned modules and routers stayed over 30 s in their exit or in Zenoh's close. Any thread may call it;
    nothing is armed where SIGALRM has a handler (pytest-timeout's, for one)."""
    if signal.getsignal(signal.SIGALRM) == signal.SIG_DFL:
        signal.alarm(seconds)
