"""The serve-on-a-thread lifecycle the simulators share, written once.

A simulator gives ``_serve`` (loop until ``_stop`` is set), ``_release`` (close its transport) and a
``THREAD_NAME``; the base starts the daemon thread, stops and joins it, releases the transport exactly once
and acts as a context manager.
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from typing import ClassVar, Self


class BackgroundServer(ABC):
    """Start/stop/context-manager lifecycle of a simulator served by one daemon thread."""

    THREAD_NAME: ClassVar[str] = "sim"
    JOIN_TIMEOUT: ClassVar[float] = 5.0

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._released = False

    def start(self) -> Self:
        self._thread = threading.Thread(target=self._serve, name=self.THREAD_NAME, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the transport; safe to call more than once."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self.JOIN_TIMEOUT)
        if not self._released:
            self._released = True
            self._release()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @abstractmethod
    def _serve(self) -> None:
        """Serve until ``self._stop`` is set (runs on the thread)."""

    @abstractmethod
    def _release(self) -> None:
        """Close the transport (listener socket, pty fds); called once, after joining the thread."""
