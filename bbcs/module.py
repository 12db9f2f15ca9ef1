"""The ``Module`` base every module process stands on: ``main()`` runs one event loop.

A module declares its slots and a handler per input (``on_<slot>``); the base does the rest: it joins the
robot's bus, validates every datum before a handler sees it, reports errors on the ERROR slot, routes inputs to
the slot numbers the manager puts in CONTROL_ENTRADA, holds a liveliness token, answers a schema query, and
stops cleanly on SIGINT/SIGTERM (undeclare everything, close the session, exit 0).

**One loop, one thread.** The loop (the thread that called ``run()``) takes the typed events of :mod:`bbcs.events`
(an input datum, a tick, a route change, stop), decodes (= validates) and calls the module's code. The module's
first stream input is a Zenoh FIFO channel (``queue`` samples) that the loop drains in batches and blocks on when
idle: no Python runs on Zenoh's thread for it and there is no second thread hop. Every other input has a Zenoh
callback that only enqueues; what is queued is handled before the next batch of the channel input. While the loop
sits in the channel's ``recv()``, a timer thread wakes it (heartbeat and tick deadlines, ``call_soon``, stop, a
queued input) with an empty session-local sample on that input's key, tagged ``WAKE``, that no handler sees.
The heartbeat is published by the same loop, so a stuck handler stops
the heartbeat and the manager's watchdog sees it. Other threads of a module hand work to the loop with
``call_soon(fn)``; ``self.lock`` is held around every handler for modules that still share state with their own
threads.

**Slot semantics in the loop.** An unsafe input keeps only its newest sample: a new one replaces a sample not yet
handled. A safe input hands every sample over in order; when ``queue`` samples wait, Zenoh's receiving thread
blocks (on the full channel, or in the callback), so Zenoh stops reading that link and the reliable BLOCK publisher
is slowed down (reported by the publisher as back-pressure).
A safe state input first gets the publisher's cached last value (late joiner).

**Safety first.** Local events and safe inputs are handled in arrival order; an unsafe input (bulk: perception,
targets) waits until no safe work is queued, one of them still handled per cycle (bbcs/priority.py). The
heartbeat goes out on Zenoh's ``interactive_high`` priority, ahead of bulk data on a busy link.

**Routing switch (one clear point).** On a new CONTROL_ENTRADA the new source is subscribed at once but held;
the old subscriber is undeclared and every datum it had already received is handled; ``on_route_change`` runs;
the acknowledgement is published on ``@route``; only then is the new source's data handled.
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import msgspec
import zenoh
import zenoh.ext

from bbcs import keys
from bbcs import lockstep as _lockstep
from bbcs.clock import WALL, Clock, SimClock
from bbcs.codec import encode, leaf_field, type_name, violates_constraint
from bbcs.conf import ConfError
from bbcs.context import ModuleContext, load_context
from bbcs.errors import EXIT_CONFIG, BusErrorCode, SessionError, SlotError
from bbcs.events import Event, Input, RouteChange, Stop, Tick
from bbcs.module_inputs import (
    _LIVE,
    _STOP,
    WAKE,
    InputReaders,
    _Marker,
    _Reader,
)
from bbcs.module_routing import RuntimeRouting
from bbcs.priority import SafetyFirst
from bbcs.routing import IGNORE, RouteAck
from bbcs.session import open_session
from bbcs.slots import Direction, Kind, Publisher, Safety, SlotSpec
from bbcs.stop_signals import exit_deadline, forward_stop_signals
from bbcs.wire import declare_schema_queryable

HEARTBEAT_PERIOD_S = 1.0


class Heartbeat(msgspec.Struct, frozen=True, kw_only=True):
    """Published from the module's event loop: proof that the loop (not only Zenoh's threads) is alive."""

    module: str
    seq: int
    pid: int
    restart_count: int
    errors: int


@dataclass(frozen=True)
class Control:
    """The CONTROL_ENTRADA of a module: its struct type and which field routes which input slot."""

    type: type[msgspec.Struct]
    routes: dict[str, str]
    """CONTROL_ENTRADA field name → input slot name."""
    slot: str = "control_entrada"



CHANNEL_BATCH = 256
"""Samples the loop takes from its channel input in one go before it looks at timers and other inputs."""


class Module(InputReaders, RuntimeRouting):
    """Subclass, declare ``slots`` (and ``control``), write ``on_<input>`` handlers, call ``main()``."""

    name: ClassVar[str] = "module"
    """Default instance name (the manifest may run several instances under other names)."""
    slots: ClassVar[tuple[SlotSpec[Any], ...]] = ()
    control: ClassVar[Control | None] = None
    error_slot: ClassVar[str | None] = None
    """Name of the output slot that carries error codes (its struct has exactly one int field)."""
    field_codes: ClassVar[Mapping[tuple[str, str], int]] = {}
    """Per-field codes for out-of-range data: ``(slot, field)`` → code (others get OUT_OF_RANGE)."""
    tick_period: float | None = None
    """Call ``on_tick`` this often from the event loop (None: never)."""
    exact_key_inputs: ClassVar[frozenset[str]] = frozenset()
    """Inputs fed only by a put on their exact key (CONTROL_ENTRADA always is): a wildcard put that intersects
    them is dropped and counted (:mod:`bbcs.ingress`, KEY_REFUSED once a second at most)."""

    _inputs: ClassVar[dict[str, SlotSpec[Any]]]
    _outputs: ClassVar[dict[str, SlotSpec[Any]]]
    _routed: ClassVar[frozenset[str]]
    _channel_slot: ClassVar[str | None]
    _error_field: ClassVar[str | None]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        specs = list(cls.slots)
        if cls.control is not None:
            specs.append(SlotSpec(cls.control.slot, cls.control.type, Direction.IN, Kind.STATE, Safety.SAFE))
        names = [s.name for s in specs]
        dupes = {n for n in names if names.count(n) > 1}
        if dupes:
            raise SlotError(f"{cls.__name__}: slot name(s) declared twice: {sorted(dupes)}")
        cls._inputs = {s.name: s for s in specs if s.direction is Direction.IN}
        cls._outputs = {s.name: s for s in specs if s.direction is Direction.OUT}
        routed: set[str] = set()
        if cls.control is not None:
            fields = set(cls.control.type.__struct_fields__)
            for field, slot in cls.control.routes.items():
                if field not in fields:
                    raise SlotError(f"{cls.__name__}: {cls.control.type.__name__} has no field {field!r}")
                if slot not in cls._inputs or slot == cls.control.slot:
                    raise SlotError(f"{cls.__name__}: control field {field!r} routes unknown input {slot!r}")
                if cls._inputs[slot].peer is not None:
                    raise SlotError(f"{cls.__name__}: input {slot!r} has a fixed peer and cannot be routed")
                routed.add(slot)
        cls._routed = frozenset(routed)
        cls._channel_slot = next((s.name for s in specs if s.direction is Direction.IN and s.kind is Kind.STREAM), None)
        for name in cls._inputs:
            if name != (cls.control.slot if cls.control else None) and not callable(getattr(cls, f"on_{name}", None)):
                raise SlotError(f"{cls.__name__}: input slot {name!r} has no handler on_{name}()")
        cls._error_field = None
        if cls.error_slot is not None:
            spec = cls._outputs.get(cls.error_slot)
            if spec is None:
                raise SlotError(f"{cls.__name__}: error_slot {cls.error_slot!r} is not an output slot")
            fields_ = spec.type.__struct_fields__
            if len(fields_) != 1:
                raise SlotError(f"{cls.__name__}: error struct {spec.type.__name__} must have exactly one int field")
            cls._error_field = fields_[0]

    # ---------------------------------------------------------------- lifecycle

    def __init__(self, context: ModuleContext) -> None:
        keys.validate_name(context.robot, "robot name")
        keys.validate_name(context.module, "module name")
        self.context = context
        self.robot = context.robot
        self.module = context.module
        self.log = logging.getLogger(f"cromat.{context.module}")
        self.lock = threading.RLock()
        self.session: zenoh.Session | None = None
        self._stop = threading.Event()
        self._bbcs_stopping = False
        self._closed = False
        self._bbcs_queue: queue.SimpleQueue[tuple[_Reader | None, Any]] = queue.SimpleQueue()
        self._bulk: SafetyFirst[_Reader] = SafetyFirst()
        """Unsafe inputs whose newest value waits: handled once no safe work is queued (bbcs/priority.py)."""
        self._outputs_by_name: dict[str, Any] = {}
        self._readers: dict[str, _Reader] = {}
        self._routes: dict[str, int] = {}
        self._ack_pub: Any = None
        self._heartbeat_pub: Publisher[Heartbeat] | None = None
        self._entities: list[Any] = []
        self._running = False
        self._loop_thread: threading.Thread | None = None
        self._channel_reader: _Reader | None = None
        """The live channel reader the loop drains and blocks on (None: the loop blocks on its queue)."""
        self._blocked_on: _Reader | None = None
        """Set while the loop sits in that channel reader's ``recv()``: waking it takes a session-local sample."""
        self._armed = float("inf")
        self._due = False
        """Set by the timer thread once the armed deadline (heartbeat, tick) has passed."""
        self._kick = threading.Event()
        self._wake_requested = False
        self._timer_stop = False
        self._timer_thread: threading.Thread | None = None
        self.sim = _lockstep.settings_from_env()
        """Lockstep simulation settings (CROMAT_SIM), or None: the wall clock, no lockstep."""
        self.bbcs_clock: Clock = WALL if self.sim is None else SimClock()
        """The robot's one clock (bbcs/clock.py): timers, heartbeats and every timeout of the module read it."""
        self._member: _lockstep.Member | None = None
        self._ask: _lockstep.Ask | None = None
        self._activity = 0
        self.error_count = 0
        self.rejected = 0
        self.dropped_after_switch = 0
        """Samples of an old route's subscriber that arrived after its switch point (never handled)."""

    @property
    def restart_count(self) -> int:
        return self.context.restart_count

    @property
    def is_restart(self) -> bool:
        return self.context.restart_count > 0

    @property
    def routes(self) -> dict[str, int]:
        """Input slot name → slot number currently read (-1 ignored)."""
        return dict(self._routes)

    def on_start(self) -> None:
        """Called once the bus is up, before any input is handled (open devices, publish initial state)."""

    def on_tick(self) -> None:
        """Called every ``tick_period`` seconds from the event loop, under the module lock."""

    def on_stop(self) -> None:
        """Called once when the module stops, under the module lock, before the bus is closed."""

    def on_route_change(self, routes: dict[str, int]) -> None:
        """Called at the switch point of a route change (old source drained, new one not yet handled)."""

    def lockstep_busy(self) -> str:
        """In lockstep: why the module's own threads have not finished what it was given ('' = finished)."""
        return ""

    def lockstep_counts(self) -> dict[str, int]:
        """In lockstep: device counters the simulator compares with its own (docs/simulation.md)."""
        return {}

    def _on_ask(self, ask: _lockstep.Ask) -> None:
        """A lockstep ask (Zenoh's thread): the loop takes the new time and answers once it is idle."""
        self._bbcs_queue.put((None, ask))
        if self._blocked_on is not None:
            self._wake()

    def _take_ask(self, ask: _lockstep.Ask) -> None:
        assert isinstance(self.bbcs_clock, SimClock)
        self.bbcs_clock.advance(ask.now)
        self._ask = ask

    def _answer_ask(self) -> None:
        ask, self._ask = self._ask, None
        if ask is not None and self._member is not None:
            with self.lock:
                busy, counts = self.lockstep_busy(), self.lockstep_counts()
            self._member.answer(ask, self._activity, busy, counts)

    def request_stop(self) -> None:
        """Ask the event loop to stop, from any thread (not from a signal handler: it takes locks; see
        bbcs.stop_signals)."""
        self._bbcs_stopping = True
        self._stop.set()
        self._bbcs_queue.put((None, _STOP))
        self._wake()

    def call_soon(self, fn: Callable[[], Any]) -> None:
        """Run ``fn()`` on the event loop, in arrival order with the inputs (for a module's own threads)."""
        self._bbcs_queue.put((None, fn))
        if self._blocked_on is not None:
            self._wake()

    def _wake(self) -> None:
        """Wake a loop blocked on its channel reader: something is in its queue. The timer thread sends the wake
        sample, never the caller: from the loop's own thread (a signal handler run inside ``recv()``) a put into
        a full channel would never return, and a caller's thread may be a daemon still inside Zenoh's ``put`` when
        the woken loop closes the session and the interpreter exits (the timer thread is joined before that)."""
        if self._blocked_on is None:
            return
        self._wake_requested = True
        self._kick.set()

    def _wake_now(self) -> None:
        reader = self._blocked_on
        if reader is None or self.session is None:
            return
        self._blocked_on = None  # one wake is enough; the loop re-checks everything before it blocks again
        try:
            self.session.put(reader.key, b"", attachment=WAKE, allowed_destination=zenoh.Locality.SESSION_LOCAL)
        except Exception as exc:  # the session is closing: the loop is on its way out anyway
            self.log.debug("wake: %s", exc)

    def _timer(self) -> None:
        """Wakes a loop blocked on its channel reader at its next deadline (heartbeat, tick) or when asked."""
        kick = self._kick
        monotonic = self.bbcs_clock.monotonic
        while not self._timer_stop:
            delay = self._armed - monotonic()
            if delay > 0 and not self._wake_requested:
                kick.wait(delay if delay < 3600 else None)
                kick.clear()
                continue
            if delay <= 0:
                self._due = True  # what the loop's inner cycle looks at instead of reading the clock per datum
            self._wake_requested = False
            self._wake_now()
            kick.wait(0.01)  # until the loop re-arms a later deadline (it does each time before it blocks)
            kick.clear()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def run(self) -> None:
        """Join the bus, run the event loop until ``request_stop()``, then undeclare everything and close."""
        self.session = open_session(self.context.bus, module=True)
        try:
            if isinstance(self.bbcs_clock, SimClock):  # restarted mid-simulation: the time before any input
                now = _lockstep.current_time(self.session, self.robot)
                if now is not None:
                    self.bbcs_clock.advance(now)
            self._declare()
            with self.lock:
                self.on_start()
            self._running = True
            for reader in list(self._readers.values()):
                self._release(reader)
            # alive only now: everything declared, on_start done (its own subscriptions too), inputs flowing
            self._entities.append(self.session.liveliness().declare_token(keys.alive_key(self.robot, self.module)))
            if self.sim is not None:  # a lockstep member from now on (docs/simulation.md)
                self._member = _lockstep.Member(self.session, self.robot, self.module, self._on_ask)
            self._serve()
        finally:
            self._shutdown()

    def _serve(self) -> None:
        """The event loop: inputs, route changes and calls in arrival order; heartbeat and tick between them.

        What the queue holds (local events, callback inputs) is handled first, then up to ``CHANNEL_BATCH`` samples
        of the channel reader; with nothing to do the loop blocks on the channel reader's ``recv()`` (the timer
        thread and the queue's producers wake it) or, without one, on the queue with the next deadline."""
        self._loop_thread = threading.current_thread()
        if self._channel_slot is not None:
            self._timer_thread = threading.Thread(target=self._timer, name=f"{self.module}-timer", daemon=True)
            self._timer_thread.start()
        period = self.tick_period
        monotonic = self.bbcs_clock.monotonic
        next_tick = monotonic() + period if period else float("inf")
        next_beat = monotonic()
        seq = 0
        q = self._bbcs_queue
        get = q.get
        take = q.get_nowait
        empty = q.empty
        bulk = self._bulk

        def safe_waiting() -> bool:
            return not empty()

        handle = self._handle_sample
        drain = self._drain_channel
        handle_one = self._handle_channel_sample
        while not self._bbcs_stopping:
            self._due = False
            now = monotonic()
            if now >= next_beat:
                seq += 1
                if self._heartbeat_pub is not None:
                    self._heartbeat_pub.publish(Heartbeat(module=self.module, seq=seq, pid=os.getpid(),
                                                          restart_count=self.restart_count,
                                                          errors=self.error_count))
                next_beat = now + HEARTBEAT_PERIOD_S
            if now >= next_tick:
                self.handle_event(_TICK)
                next_tick = max(next_tick + (period or 0.0), now)
                continue
            busy = False
            for _ in range(q.qsize()):  # local events and callback inputs, in arrival order (those queued now)
                if self._bbcs_stopping:
                    break
                try:  # never a blocking get: a route switch handled here drains what was queued behind it
                    reader, item = take()
                except queue.Empty:
                    break
                if reader is not None:
                    if reader.unsafe:  # bulk: after the safe work (bbcs/priority.py)
                        bulk.defer(reader)
                        continue
                    handle(reader, item)
                else:
                    self._handle_local(item)
                busy = True
            channel = self._channel_reader
            if channel is not None and not self._bbcs_stopping and (n := drain(channel, CHANNEL_BATCH)):
                busy = True
                self._activity += n
            if bulk and not self._bbcs_stopping:
                for reader in bulk.take(safe_waiting):
                    handle(reader, None)
                busy = True
            if busy or self._bbcs_stopping:
                continue
            if self._ask is not None:  # lockstep: idle, every due timer run: the step is handled here
                self._answer_ask()
                continue
            deadline = min(next_tick, next_beat)
            if channel is None:
                self._armed = float("inf")
                try:
                    reader, item = get(True, max(0.0, deadline - monotonic()))
                except queue.Empty:
                    continue
                if reader is not None and reader.unsafe:
                    bulk.defer(reader)  # handled at the next cycle, once what is queued meanwhile is
                elif reader is not None:
                    handle(reader, item)
                else:
                    self._handle_local(item)
                continue
            if deadline != self._armed:
                self._armed = deadline
                self._kick.set()
            # The idle cycle: block on the channel reader, handle what it gives, block again, for as long as
            # nothing else needs the loop (queue empty, no deadline due, not stopping). It is kept this short
            # because every step between a handler's publish and the next block was measured to add to that
            # datum's latency (docs/performance.md, "the loop's idle cycle").
            recv = channel.chan.recv
            try_recv = channel.chan.try_recv
            while True:
                self._blocked_on = channel
                # re-checked after announcing the block: no lost wake-up
                if self._due or self._bbcs_stopping or not empty() or self._channel_reader is not channel:
                    self._blocked_on = None
                    break
                try:
                    sample = recv()
                except zenoh.ZError as exc:  # a closed channel (its session is closing): nothing more will come
                    self._blocked_on = None
                    self.log.debug("input %s: %s", channel.spec.name, exc)
                    self._channel_reader = None
                    break
                self._blocked_on = None
                handle_one(channel, sample)
                try:
                    sample = try_recv()
                except zenoh.ZError:
                    break
                if sample is not None:  # a burst: handle this one (unless a handler asked to stop), then batches
                    if not self._bbcs_stopping:
                        handle_one(channel, sample)
                    break

    def _drain_channel(self, reader: _Reader, limit: int) -> int:
        """Handle up to ``limit`` samples waiting in a channel reader, in order; returns how many were taken.

        The hot path, written out: per datum one ``try_recv``, the payload's bytes, decode (= validate) and the
        handler; a wake sample is told apart only when it fails to decode. The module lock is taken once per
        batch, not per datum (a lock round trip costs more than the decode here): every handler still runs
        under it, and a module's own thread waits at most one batch for it."""
        try_recv = reader.chan.try_recv
        decode = reader.decode
        handler = reader.handler
        n = 0
        sample = try_recv() if reader.state == _LIVE else None
        if sample is None:
            return 0
        try:
            with self.lock:
                while True:
                    n += 1
                    payload = sample.payload.to_bytes()
                    try:
                        value = decode(payload)
                    except msgspec.MsgspecError as exc:
                        if payload:  # empty: no datum (see WAKE)
                            self._reject(reader.spec.name, reader.key, exc, payload)
                    else:
                        try:
                            handler(value)
                        except Exception:
                            self._handler_failed(reader.spec.name)
                    if n >= limit or self._bbcs_stopping or reader.state != _LIVE:
                        break
                    sample = try_recv()
                    if sample is None:
                        break
        except zenoh.ZError as exc:  # a closed channel (its session is closing): nothing more will come
            self.log.debug("input %s: %s", reader.spec.name, exc)
            if self._channel_reader is reader:
                self._channel_reader = None
        return n

    def _handle_channel_sample(self, reader: _Reader, sample: Any) -> None:
        """One datum of a channel reader (the one ``recv()`` returned, or a route switch's drain)."""
        payload = sample.payload.to_bytes()
        try:
            value = reader.decode(payload)
        except msgspec.MsgspecError as exc:
            if payload:  # empty: no datum (see WAKE)
                self._reject(reader.spec.name, reader.key, exc, payload)
            return
        self._activity += 1
        lock = self.lock
        lock.acquire()  # not ``with``: half the cost here, on every idle datum's path
        try:
            reader.handler(value)
        except Exception:
            self._handler_failed(reader.spec.name)
        finally:
            lock.release()

    def _handler_failed(self, slot: str) -> None:
        self.log.exception("handler on_%s failed", slot)
        self.report_error(BusErrorCode.HANDLER_FAILED, f"handler on_{slot} raised")

    def _handle_local(self, item: Any) -> None:
        if item is _STOP or isinstance(item, _Marker):
            return
        if isinstance(item, _lockstep.Ask):  # the stepper's question: not activity of the module's own
            self._take_ask(item)
            return
        self._activity += 1
        if isinstance(item, (Input, Tick, RouteChange, Stop)):
            self.handle_event(item)
        else:
            with self.lock:
                self._call_safely("call_soon", item)

    def handle_event(self, event: Event) -> None:
        """Handle one typed event now, on the calling thread (the loop; ``bbcs.testing`` in unit tests)."""
        if isinstance(event, Input):
            spec = self._inputs.get(event.slot)
            if spec is None:
                raise SlotError(f"{self.module}: no input slot {event.slot!r}")
            value = event.value
            payload = value if isinstance(value, (bytes, bytearray, memoryview)) else encode(value)
            self._handle_payload(spec, self._handler_for(spec), bytes(payload), self._key_of(spec))
        elif isinstance(event, Tick):
            with self.lock:
                self._call_safely("tick", self.on_tick)
        elif isinstance(event, RouteChange):
            self._apply_routes(dict(event.routes), request=dict(event.routes), publish_ack=True)
        elif isinstance(event, Stop):
            self.request_stop()

    def _declare(self) -> None:
        assert self.session is not None
        s = self.session
        for name, spec in self._outputs.items():
            self._outputs_by_name[name] = Publisher(s, spec.key(self.robot, self.module), spec)
        self._ack_pub = Publisher(s, keys.route_ack_key(self.robot, self.module),
                                  SlotSpec("route", RouteAck, Direction.OUT, Kind.STATE, Safety.SAFE))
        self._heartbeat_pub = Publisher(s, keys.heartbeat_key(self.robot, self.module),  # ahead of bulk data
                                        SlotSpec("heartbeat", Heartbeat, Direction.OUT, Kind.STATE, Safety.UNSAFE,
                                                 priority="interactive_high"))
        self._entities.append(declare_schema_queryable(s, keys.schema_key(self.robot, self.module),
                                                       self.describe))
        self._declare_inputs()

    def _declare_inputs(self) -> None:
        """Subscribe the fixed inputs (held until running) and apply the initial routes."""
        for name, spec in self._inputs.items():
            if name not in self._routed:
                self._readers[name] = self._make_reader(spec, spec.key(self.robot, self.module), IGNORE)
        initial = {slot: self.context.routes.get(slot, IGNORE) for slot in sorted(self._routed)}
        self._apply_routes(initial, request=initial, publish_ack=bool(self.context.routes))

    def _shutdown(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._bbcs_stopping = True
        self._stop.set()
        self._timer_stop = True
        self._kick.set()
        try:
            if self._member is not None:
                self._member.close()
            with self.lock:
                self._call_safely("stop", self.on_stop)
        finally:
            for reader in list(self._readers.values()):
                self._close_reader(reader)
            self._readers.clear()
            if self._timer_thread is not None:  # after the readers: a wake put into a full channel has returned
                self._timer_thread.join(5)
            for pub in [*self._outputs_by_name.values(), self._ack_pub, self._heartbeat_pub]:
                if pub is not None:
                    pub.close()
            for entity in reversed(self._entities):
                entity.undeclare()
            self._entities.clear()
            if self.session is not None:
                self.session.close()

    # ---------------------------------------------------------------- outputs and errors

    def output(self, name: str) -> Publisher[Any]:
        """The publisher of output slot ``name`` (SlotError if there is none)."""
        try:
            return self._outputs_by_name[name]
        except KeyError:
            raise SlotError(f"{self.module}: no output slot {name!r} (or the module is not running)") from None

    def publish(self, name: str, value: msgspec.Struct) -> None:
        self.output(name).publish(value)

    def report_error(self, code: int, detail: str) -> None:
        """Log ``detail`` and publish ``code`` on the ERROR slot (every code is sent, in order)."""
        self.error_count += 1
        self.log.warning("error %d: %s", code, detail)
        pub = self._outputs_by_name.get(self.error_slot or "")
        if pub is not None and self._error_field is not None:
            pub.publish(pub.spec.type(**{self._error_field: int(code)}))

    def error_code_for(self, slot: str, field: str, error: msgspec.MsgspecError, payload: bytes = b"") -> int:
        """The code reported when a datum on ``slot`` fails at ``field`` (``$.a.b[2].c``): the ``field_codes``
        entry when the value there has the declared type but breaks the field's declared constraints (its
        ``Meta``), else OUT_OF_RANGE; MALFORMED for anything that does not decode as the slot's struct."""
        if isinstance(error, msgspec.ValidationError) and violates_constraint(self._inputs[slot].type, field,
                                                                              payload):
            return self.field_codes.get((slot, leaf_field(field)), BusErrorCode.OUT_OF_RANGE)
        return BusErrorCode.MALFORMED

    # ---------------------------------------------------------------- schema query

    def described_keys(self) -> Mapping[str, Any]:
        """Keys this module publishes or answers besides its slots: key → struct type, or for a queryable
        ``{"request": type, "reply": type}`` (override to add them to ``@schema``)."""
        return {}

    def describe(self) -> dict[str, Any]:
        """What ``cromat/<robot>/<module>/@schema`` answers: every slot's JSON Schema, the @-keys' too."""
        from bbcs.wire import describe_types

        return {
            "module": self.module, "robot": self.robot, "class": type_name(type(self)),
            "slots": {name: spec.describe() for name, spec in {**self._inputs, **self._outputs}.items()},
            "control": None if self.control is None else {
                "slot": self.control.slot, "type": type_name(self.control.type), "routes": self.control.routes},
            "routes": self._routes,
            "keys": describe_types({keys.route_ack_key(self.robot, self.module): RouteAck,
                                    keys.heartbeat_key(self.robot, self.module): Heartbeat,
                                    **self.described_keys()}),
        }

    # ---------------------------------------------------------------- process entry

    @classmethod
    def main(cls, argv: list[str] | None = None) -> int:
        """Entry point of ``python -m modules.<name>``: returns the process exit code (EXIT_CONFIG = 78 when
        construction or ``on_start`` raises a ConfError: the manager does not retry that)."""
        logging.basicConfig(level=os.environ.get("CROMAT_LOG", "INFO"),
                            format="%(asctime)s %(name)s %(levelname)s %(message)s")
        context = load_context(argv, f"python -m {cls.__module__}", cls.name)
        log = logging.getLogger(f"cromat.{context.module}")
        try:
            module = cls(context)
        except ConfError as exc:
            log.error("configuration error: %s", exc)
            return EXIT_CONFIG
        except Exception as exc:
            log.error("cannot start: %s", exc)
            return 2
        stopped = threading.Event()
        parent = os.getppid()
        restore_signals = _stop_on_signal_or_orphan(module, stopped, parent)
        try:
            module.run()
        except ConfError as exc:
            module.log.error("configuration error: %s", exc)
            return EXIT_CONFIG
        except SessionError as exc:
            module.log.error("%s", exc)
            return 2
        finally:
            stopped.set()
            restore_signals()  # stopped: from here a stop signal simply ends the process, even one whose exit hangs
            if os.getppid() != parent:
                exit_deadline(ORPHAN_STOP_GRACE_S)
        return 0


ORPHAN_STOP_GRACE_S = 5
"""Seconds a module whose parent is gone waits for its loop to stop after SIGINT/SIGTERM before it exits anyway,
and that its exit may then take before the kernel ends it (SIGALRM)."""


def _stop_on_signal_or_orphan(module: Module, stopped: threading.Event, parent: int) -> Callable[[], None]:
    """Make sure a stop signal, or the death of the parent, stops the process even when its loop cannot see it;
    returns the function that puts the previous signal handlers back.

    Signals are handled on a helper thread (bbcs.stop_signals): ``request_stop`` takes locks, which a handler run
    on the main thread must not (one interrupted the module's own ``Event.set()`` at shutdown: a deadlock). The
    loop may also sit in a Zenoh ``recv()``, in Rust; it is normally woken by a sample its own timer puts through
    the router. When the manager dies, every child gets SIGTERM at once (PR_SET_PDEATHSIG), the router among
    them, so that wake may never come and the module would outlive its manager. So a watch thread also checks
    every second that the parent is still there; once it is gone, the loop is asked to stop, the kernel's
    deadline is armed once (bbcs.stop_signals.exit_deadline, which holds through the interpreter's exit), and
    if the loop has not stopped within ``ORPHAN_STOP_GRACE_S`` of the request, the process exits. With a live
    parent nothing more happens: the manager's own grace and SIGKILL decide."""
    asked: list[float] = []

    def ask(_signum: int = 0) -> None:
        if not asked:
            asked.append(time.monotonic())
        module.request_stop()

    restore = forward_stop_signals(ask)

    def watch() -> None:
        orphaned = False
        while not stopped.wait(1.0):
            if os.getppid() == parent:
                continue
            if not orphaned:
                orphaned = True
                exit_deadline(ORPHAN_STOP_GRACE_S)
            if not asked:
                ask()
            elif time.monotonic() - asked[0] >= ORPHAN_STOP_GRACE_S and not stopped.is_set():
                # no logging call here: a lock held by a blocked thread would hang it
                os.write(2, f"{module.module}: stop signal, parent gone and the loop still not stopped after "
                            f"{ORPHAN_STOP_GRACE_S:g} s: exiting\n".encode())
                os._exit(0)

    threading.Thread(target=watch, name=f"{module.module}-stop-watch", daemon=True).start()
    return restore


_TICK = Tick()
