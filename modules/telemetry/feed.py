"""Reading another process's output (the DSP's telemetry and errors) from inside a module.

These keys are fixed, not routed through CONTROL_ENTRADA, so the Module base does not declare them. A feed is
a Zenoh subscriber with a channel and one thread that decodes each sample and hands it to a handler under the
module lock — the same discipline as the base's inputs, so handlers need no locks of their own and a slow
handler never stalls Zenoh's own threads. Samples that do not decode are counted and dropped.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any, Generic, TypeVar

import msgspec
import zenoh

T = TypeVar("T", bound=msgspec.Struct)
JOIN_TIMEOUT_S = 2.0


class Feed(Generic[T]):
    """Subscribe ``key`` as ``type``; ``newest_only``: a RingChannel(1) (telemetry), else all, in order."""

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        type_: type[T],
        handler: Callable[[T], None],
        lock: Any,
        *,
        newest_only: bool,
        queue: int = 1024,
    ) -> None:
        self.key = key
        self.received = 0
        self.undecodable = 0
        self._decode = msgspec.msgpack.Decoder(type_).decode
        self._handler = handler
        self._lock = lock
        self._log = logging.getLogger(f"cromat.feed.{key}")
        channel = zenoh.handlers.RingChannel(1) if newest_only else zenoh.handlers.FifoChannel(queue)
        self._sub = session.declare_subscriber(key, channel)
        self._closed = False
        self._thread = threading.Thread(target=self._drain, name=f"feed {key}", daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        try:
            for sample in self._sub:
                if self._closed:
                    continue
                try:
                    value = self._decode(sample.payload.to_bytes())
                except msgspec.MsgspecError as exc:
                    self.undecodable += 1
                    self._log.warning("undecodable sample dropped (%d so far): %s", self.undecodable, exc)
                    continue
                self.received += 1
                while not self._lock.acquire(timeout=0.05):
                    if self._closed:  # close() may be waiting for this thread while holding the lock
                        return
                try:
                    if not self._closed:
                        self._handler(value)
                except Exception:
                    self._log.exception("feed handler failed")
                finally:
                    self._lock.release()
        except zenoh.ZError:
            pass  # undeclared

    def close(self) -> None:
        """Undeclare and wait for the thread (safe also while holding the lock the handler takes)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._sub.undeclare()
        except Exception as exc:  # racing a session close must not stop the shutdown
            self._log.debug("undeclare: %s", exc)
        if self._thread is not threading.current_thread():
            self._thread.join(JOIN_TIMEOUT_S)
