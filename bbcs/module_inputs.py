"""A module's inputs: one reader per input slot, their hand-over to the loop, back-pressure and validation.

A mixin of :class:`bbcs.module.Module` (the loop, its queue and its clock live there), kept apart because it is one
job: subscribe each input where its route points, hand every sample to the loop without running Python on Zenoh's
threads where it can (a channel input), hold a safe input's publisher back when the loop is behind, and decode
(= validate) before a handler sees anything.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh
import zenoh.ext

from bbcs.codec import field_of
from bbcs.errors import BusErrorCode
from bbcs.events import Stop
from bbcs.ingress import ExactKeyGuard
from bbcs.slots import Kind, Safety, SlotSpec, declare_reader

BACKPRESSURE_POLL_S = 0.1
"""How often a receiving callback blocked on a full safe queue re-checks for stop."""

_HELD, _LIVE, _DRAINING, _CLOSED = range(4)

WAKE = b"bbcs-wake"
"""Attachment of the empty, session-local sample that wakes a loop blocked on its channel input (never data:
a datum is never empty msgpack). Any empty payload is no datum and is dropped unseen: a wake, or a state slot's
value withdrawn by its publisher (a Zenoh delete, live or replayed to a late joiner by the publisher's cache as
an empty put; the Module Manager withdraws the mode of a movement task that has ended)."""


class _Marker:
    """The switch point of a route change in the loop's queue."""

    __slots__ = ()


_STOP = Stop()


def rereads(spec: SlotSpec[Any]) -> bool:
    """Whether an input routed to a new source while the module runs asks that source for its current value: an
    unsafe **state** input (newest only, best effort), which otherwise would see nothing until the source next
    publishes; a safe state input gets it from its history anyway, a stream has no current value (docs/bus.md,
    "Routing inputs at run time")."""
    return spec.safety is Safety.UNSAFE and spec.kind is Kind.STATE


def declare_rereading(session: zenoh.Session, key: str, spec: SlotSpec[Any], handler: Any) -> Any:
    """The subscriber of an input just routed to ``key``: live samples as a plain one, and first the source's
    current value if its publisher keeps one (a safe state slot's advanced publisher cache; a best-effort publisher
    keeps none and its next datum is the first). zenoh.ext orders the cached value and live samples of one
    publisher by their sequence numbers, so an older value never follows a newer one."""
    return zenoh.ext.declare_advanced_subscriber(
        session, key, handler, history=zenoh.ext.HistoryConfig(detect_late_publishers=False, max_samples=1))


class _Reader:
    """One input's subscriber and its hand-over to the loop.

    A *channel* reader (the module's first stream input) has a Zenoh FIFO channel as its handler: Zenoh's thread
    never runs Python for it, the loop takes its samples in batches and blocks on it when idle. Other readers
    have a callback that only hands the sample to the loop's queue."""

    __slots__ = ("spec", "key", "number", "sub", "chan", "handler", "decode", "is_control", "state", "lock", "held",
                 "latest", "unsafe", "enqueued", "handled", "waiting", "room")

    def __init__(self, spec: SlotSpec[Any], key: str, number: int, handler: Callable[[Any], Any],
                 is_control: bool) -> None:
        self.spec = spec
        self.key = key
        self.number = number
        self.sub: Any = None
        self.chan: Any = None
        """The Zenoh channel (``try_recv``/``recv``) of a channel reader, else None."""
        self.handler = handler
        self.decode = spec.codec.decode
        self.is_control = is_control
        self.state = _HELD
        self.lock = threading.Lock()
        self.held: list[Any] = []
        self.latest: Any = None
        self.unsafe = spec.safety is Safety.UNSAFE
        self.enqueued = itertools.count(1)
        self.handled = 0
        self.waiting = False
        self.room = threading.Condition(threading.Lock())


class InputReaders:
    """The inputs of :class:`~bbcs.module.Module` (a mixin: the module holds the loop and its state)."""

    def _handler_for(self, spec: SlotSpec[Any]) -> Callable[[Any], Any]:
        if self.control is not None and spec.name == self.control.slot:
            return self._on_control
        return getattr(self, f"on_{spec.name}")

    def _key_of(self, spec: SlotSpec[Any]) -> str:
        reader = self._readers.get(spec.name)
        return reader.key if reader is not None else spec.key(self.robot, self.module)

    def _make_reader(self, spec: SlotSpec[Any], key: str, number: int, reread: bool = False) -> _Reader:
        """Subscribe; the reader holds what it receives until ``_release`` (running, or past a switch point).
        ``reread``: also ask the source's cache for its current value (:func:`declare_rereading`).

        The module's first stream input gets a Zenoh FIFO channel of ``queue`` samples (a full channel blocks
        Zenoh's thread: back-pressure, nothing dropped), unless another input reads the same key (the wake sample
        would reach it too); every other input a callback into the loop's queue."""
        is_control = self.control is not None and spec.name == self.control.slot
        reader = _Reader(spec, key, number, self._handler_for(spec), is_control)
        if self.session is not None:
            declare = declare_rereading if reread else declare_reader
            shared = any(r.key == key for r in self._readers.values() if r.spec.name != spec.name)
            exact = is_control or spec.name in self.exact_key_inputs
            if spec.name == self._channel_slot and not shared and not exact:
                reader.sub = declare(self.session, key, spec, zenoh.handlers.FifoChannel(spec.queue))
                reader.chan = reader.sub.handler
            elif exact:  # a wildcard put on a denied key gets no further than here (issue 32 item 6)
                guard = ExactKeyGuard(key, lambda n, k, name=spec.name: self.report_error(
                    BusErrorCode.KEY_REFUSED, f"input {name}: {n} datum(s) put on {k}, not on {key}: dropped"))
                reader.sub = declare(self.session, key, spec, guard.wrap(self._enqueuer(reader)))
            else:
                reader.sub = declare(self.session, key, spec, self._enqueuer(reader))
        return reader

    def _enqueuer(self, reader: _Reader) -> Callable[[zenoh.Sample], None]:
        """The Zenoh callback of one input: it only hands the sample to the loop (never decodes or handles)."""
        put = self._bbcs_queue.put
        lock = reader.lock
        item = (reader, None)
        if reader.unsafe:
            def newest(sample: zenoh.Sample) -> None:
                with lock:
                    fresh = reader.latest is None
                    reader.latest = sample
                    if reader.state == _HELD:
                        return
                if fresh:
                    put(item)
                    if self._blocked_on is not None:
                        self._wake()
            return newest

        bound = reader.spec.queue
        enqueued = reader.enqueued
        held = _HELD

        def in_order(sample: zenoh.Sample) -> None:
            if reader.state == held:
                with lock:
                    if reader.state == held:
                        reader.held.append(sample)
                        return
            n = next(enqueued)
            if n - reader.handled > bound:
                self._wait_for_room(reader, n)
            put((reader, sample))  # the loop wakes to a free GIL (no second wake-up) ...
            if self._blocked_on is not None:  # ... unless it sits on its channel reader
                self._wake()
        return in_order

    def _wait_for_room(self, reader: _Reader, enqueued: int) -> None:
        """Block Zenoh's receiving thread while a safe queue is full (``queue`` samples wait): back-pressure to
        the reliable publisher. Stop or a route switch end the wait (the sample is then queued all the same)."""
        with reader.room:
            reader.waiting = True
            while (enqueued - reader.handled > reader.spec.queue and not self._bbcs_stopping
                   and reader.state == _LIVE):
                reader.room.wait(BACKPRESSURE_POLL_S)
            reader.waiting = False

    def _release(self, reader: _Reader) -> None:
        """Let the loop see what the reader holds, in order, then everything it receives."""
        with reader.lock:
            if reader.state != _HELD:
                return
            if reader.chan is not None:  # its samples wait in the channel: the loop now drains it
                reader.state = _LIVE
                self._channel_reader = reader
                return
            if reader.unsafe:
                if reader.latest is not None:
                    self._bbcs_queue.put((reader, None))
            else:
                for sample in reader.held:
                    self._bbcs_queue.put((reader, sample))
                    next(reader.enqueued)
                reader.held.clear()
            reader.state = _LIVE

    def _close_reader(self, reader: _Reader) -> None:
        """Undeclare (on the loop's thread, never while it sits in ``recv()``) and drop the channel: a Zenoh
        thread blocked on a full channel is released when its receiver goes."""
        try:
            if reader.sub is not None:
                reader.sub.undeclare()
        except Exception as exc:  # an undeclare racing session close must not stop the shutdown
            self.log.debug("undeclare %s: %s", reader.key, exc)
        reader.sub = None
        reader.chan = None
        if self._channel_reader is reader:
            self._channel_reader = None
        reader.state = _CLOSED
        with reader.room:
            reader.room.notify_all()

    def _handle_sample(self, reader: _Reader, sample: Any) -> None:
        """One input datum from Zenoh, on the loop: newest-only or in-order bookkeeping, then decode and handle.
        (The hot path: everything it needs is on the reader, nothing is looked up per datum.)"""
        if reader.unsafe:
            with reader.lock:
                sample, reader.latest = reader.latest, None
            if sample is None:
                return
        else:
            reader.handled += 1
            if reader.waiting:
                with reader.room:
                    reader.room.notify_all()
        if reader.state == _CLOSED:
            self.dropped_after_switch += 1
            return
        payload = sample.payload.to_bytes()
        if not payload:  # no datum (see WAKE)
            return
        try:
            value = reader.decode(payload)
        except msgspec.MsgspecError as exc:
            self._reject(reader.spec.name, reader.key, exc, payload)
            return
        self._activity += 1
        with self.lock:
            try:
                reader.handler(value)
            except Exception:
                self.log.exception("handler on_%s failed", reader.spec.name)
                self.report_error(BusErrorCode.HANDLER_FAILED, f"handler on_{reader.spec.name} raised")

    def _handle_payload(self, spec: SlotSpec[Any], handler: Callable[[Any], Any], payload: bytes,
                        key: str) -> None:
        try:
            value = spec.codec.decode(payload)
        except msgspec.MsgspecError as exc:
            self._reject(spec.name, key, exc, payload)
            return
        with self.lock:
            try:
                handler(value)
            except Exception:
                self.log.exception("handler on_%s failed", spec.name)
                self.report_error(BusErrorCode.HANDLER_FAILED, f"handler on_{spec.name} raised")

    def _reject(self, slot: str, key: str, exc: msgspec.MsgspecError, payload: bytes) -> None:
        field = field_of(exc) if isinstance(exc, msgspec.ValidationError) else "$"
        code = self.error_code_for(slot, field, exc, payload)
        self.rejected += 1
        self.report_error(code, f"slot {slot} ({key}) field {field}: {exc}; datum dropped")

    def _call_safely(self, what: str, fn: Callable[[], Any]) -> None:
        try:
            fn()
        except Exception:
            self.log.exception("on_%s failed", what)
            self.report_error(BusErrorCode.HANDLER_FAILED, f"on_{what} raised")
