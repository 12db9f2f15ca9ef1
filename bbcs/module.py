"""The ``Module`` base every module process stands on.

A module declares its slots and a handler per input (``on_<slot>``); the base does the rest: it joins the
robot's bus, validates every datum before a handler sees it, reports errors on the ERROR slot, routes inputs to
the slot numbers the manager puts in CONTROL_ENTRADA, holds a liveliness token, answers a schema query, and
stops cleanly on SIGINT/SIGTERM (undeclare everything, close the session, exit 0).

Handlers run one at a time (a module lock), so module code needs no locks of its own. Each input has its own
receiving thread, so a slow handler on one safe input never makes an unsafe input lose its newest value.

Routing switch (one clear point): on a new CONTROL_ENTRADA the new source is subscribed at once but held; the
old subscriber is undeclared and every datum it had already received is handled; then the acknowledgement is
published on ``@route``; only then is the new source's data handled.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import msgspec
import zenoh

from bbcs import keys
from bbcs.codec import field_of, leaf_field, type_name
from bbcs.context import ModuleContext, load_context
from bbcs.errors import BusErrorCode, RouteError, SessionError, SlotError
from bbcs.routing import IGNORE, RouteAck
from bbcs.session import open_session
from bbcs.slots import Direction, Kind, Publisher, Safety, SlotSpec, declare_reader

HEARTBEAT_PERIOD_S = 1.0
JOIN_TIMEOUT_S = 2.0


class Heartbeat(msgspec.Struct, frozen=True, kw_only=True):
    """Published from the module's main loop: proof that the loop (not only Zenoh's threads) is alive."""

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


class _Reader:
    """One input's Zenoh subscriber and the thread that drains it."""

    __slots__ = ("spec", "key", "number", "sub", "thread", "gate", "received")

    def __init__(self, spec: SlotSpec[Any], key: str, number: int) -> None:
        self.spec = spec
        self.key = key
        self.number = number
        self.sub: Any = None
        self.thread: threading.Thread | None = None
        self.gate = threading.Event()
        self.received = 0


class Module:
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
    """Call ``on_tick`` this often from the main loop (None: never)."""

    _inputs: ClassVar[dict[str, SlotSpec[Any]]]
    _outputs: ClassVar[dict[str, SlotSpec[Any]]]
    _routed: ClassVar[frozenset[str]]
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
        self._closed = False
        self._outputs_by_name: dict[str, Publisher[Any]] = {}
        self._readers: dict[str, _Reader] = {}
        self._errors: deque[int] = deque()
        self._error_lock = threading.Lock()
        self._route_lock = threading.Lock()
        self._routes: dict[str, int] = {}
        self._ack_pub: Publisher[RouteAck] | None = None
        self._heartbeat_pub: Publisher[Heartbeat] | None = None
        self._entities: list[Any] = []
        self._running = False
        self.error_count = 0
        self.rejected = 0

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
        """Called every ``tick_period`` seconds from the main loop, under the module lock."""

    def on_stop(self) -> None:
        """Called once when the module stops, under the module lock, before the bus is closed."""

    def on_route_change(self, routes: dict[str, int]) -> None:
        """Called at the switch point of a route change (old source drained, new one not yet handled)."""

    def request_stop(self) -> None:
        """Ask the main loop to stop (safe from signal handlers and other threads)."""
        self._stop.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def run(self) -> None:
        """Join the bus, serve until ``request_stop()``, then undeclare everything and close the session."""
        self.session = open_session(self.context.bus)
        try:
            self._declare()
            with self.lock:
                self.on_start()
            self._flush_errors()
            with self._route_lock:
                self._running = True
                for reader in list(self._readers.values()):
                    reader.gate.set()
            # alive only now: everything declared, on_start done (its own subscriptions too), inputs flowing
            self._entities.append(self.session.liveliness().declare_token(keys.alive_key(self.robot, self.module)))
            self._serve()
        finally:
            self._shutdown()

    def _serve(self) -> None:
        period = self.tick_period
        next_tick = time.monotonic() + period if period else float("inf")
        next_beat = time.monotonic()
        seq = 0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_beat and self._heartbeat_pub is not None:
                seq += 1
                self._heartbeat_pub.publish(Heartbeat(module=self.module, seq=seq, pid=os.getpid(),
                                                      restart_count=self.restart_count, errors=self.error_count))
                next_beat = now + HEARTBEAT_PERIOD_S
            if now >= next_tick:
                with self.lock:
                    self._call_safely("tick", self.on_tick)
                next_tick = max(next_tick + (period or 0), now)
            self._stop.wait(max(0.0, min(next_tick, next_beat) - time.monotonic()))

    def _declare(self) -> None:
        assert self.session is not None
        s = self.session
        for name, spec in self._outputs.items():
            self._outputs_by_name[name] = Publisher(s, spec.key(self.robot, self.module), spec)
        self._ack_pub = Publisher(s, keys.route_ack_key(self.robot, self.module),
                                  SlotSpec("route", RouteAck, Direction.OUT, Kind.STATE, Safety.SAFE))
        self._heartbeat_pub = Publisher(s, keys.heartbeat_key(self.robot, self.module),
                                        SlotSpec("heartbeat", Heartbeat, Direction.OUT, Kind.STATE, Safety.UNSAFE))
        self._entities.append(s.declare_queryable(keys.schema_key(self.robot, self.module), self._answer_schema))
        for name, spec in self._inputs.items():
            if name not in self._routed:
                self._readers[name] = self._make_reader(spec, spec.key(self.robot, self.module), IGNORE)
        initial = {slot: self.context.routes.get(slot, IGNORE) for slot in sorted(self._routed)}
        self._apply_routes(initial, request=initial, publish_ack=bool(self.context.routes))

    def _shutdown(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        try:
            with self.lock:
                self._call_safely("stop", self.on_stop)
        finally:
            for reader in list(self._readers.values()):
                self._close_reader(reader, drain=False)
            self._readers.clear()
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
        """Log ``detail`` and queue ``code`` for the ERROR slot; every queued code is sent, in order."""
        self.error_count += 1
        self.log.warning("error %d: %s", code, detail)
        if self.error_slot is None:
            return
        with self._error_lock:
            self._errors.append(int(code))
        self._flush_errors()

    def _flush_errors(self) -> None:
        pub = self._outputs_by_name.get(self.error_slot or "")
        if pub is None or self._error_field is None:
            return
        with self._error_lock:
            while self._errors:
                code = self._errors.popleft()
                pub.publish(pub.spec.type(**{self._error_field: code}))

    def error_code_for(self, slot: str, field: str, error: msgspec.MsgspecError) -> int:
        """The code reported when a datum on ``slot`` fails at ``field`` (``$.a.b[2].c``): the ``field_codes``
        entry for an out-of-range field, else OUT_OF_RANGE; MALFORMED for anything that does not decode."""
        if isinstance(error, msgspec.ValidationError) and _is_range_error(str(error)):
            return self.field_codes.get((slot, leaf_field(field)), BusErrorCode.OUT_OF_RANGE)
        return BusErrorCode.MALFORMED

    # ---------------------------------------------------------------- inputs

    def _make_reader(self, spec: SlotSpec[Any], key: str, number: int) -> _Reader:
        """Subscribe and start the input's thread; it handles nothing until its gate opens."""
        assert self.session is not None
        reader = _Reader(spec, key, number)
        reader.sub = declare_reader(self.session, key, spec)
        is_control = self.control is not None and spec.name == self.control.slot
        handler = self._on_control if is_control else getattr(self, f"on_{spec.name}")
        reader.thread = threading.Thread(target=self._drain, args=(reader, handler, not is_control),
                                         name=f"{self.module}.{spec.name}", daemon=True)
        reader.thread.start()
        return reader

    def _close_reader(self, reader: _Reader, *, drain: bool) -> None:
        """Undeclare; with ``drain`` the reader's thread first handles everything already received."""
        if not drain:
            reader.gate.set()
        try:
            reader.sub.undeclare()
        except Exception as exc:  # an undeclare racing session close must not stop the shutdown
            self.log.debug("undeclare %s: %s", reader.key, exc)
        if reader.thread is not None and reader.thread is not threading.current_thread():
            reader.thread.join(JOIN_TIMEOUT_S)

    def _drain(self, reader: _Reader, handler: Callable[[Any], Any], locked: bool) -> None:
        """Receive, decode (= validate) and hand each datum to ``handler``, under the module lock if ``locked``.

        CONTROL_ENTRADA is handled without the lock: a route switch waits for other inputs' threads to drain.
        """
        spec = reader.spec
        decode = spec.codec.decode
        lock: Any = self.lock if locked else _NoLock()
        gate = reader.gate
        stop = self._stop
        try:
            for sample in reader.sub:
                if not gate.is_set():
                    gate.wait()
                if stop.is_set():
                    continue
                reader.received += 1
                try:
                    value = decode(sample.payload.to_bytes())
                except msgspec.MsgspecError as exc:
                    self._reject(spec.name, reader.key, exc)
                    continue
                with lock:
                    try:
                        handler(value)
                    except Exception:
                        self.log.exception("handler on_%s failed", spec.name)
                        self.report_error(BusErrorCode.HANDLER_FAILED, f"handler on_{spec.name} raised")
        except zenoh.ZError:
            pass  # the channel closed: the subscriber was undeclared

    def _reject(self, slot: str, key: str, exc: msgspec.MsgspecError) -> None:
        field = field_of(exc) if isinstance(exc, msgspec.ValidationError) else "$"
        code = self.error_code_for(slot, field, exc)
        self.rejected += 1
        self.report_error(code, f"slot {slot} ({key}) field {field}: {exc}; datum dropped")

    def _call_safely(self, what: str, fn: Callable[[], None]) -> None:
        try:
            fn()
        except Exception:
            self.log.exception("on_%s failed", what)
            self.report_error(BusErrorCode.HANDLER_FAILED, f"on_{what} raised")

    # ---------------------------------------------------------------- routing

    def _on_control(self, value: msgspec.Struct) -> None:
        assert self.control is not None
        request = {field: int(getattr(value, field)) for field in self.control.routes}
        wanted = {slot: request[field] for field, slot in self.control.routes.items()}
        self._apply_routes(wanted, request=request, publish_ack=True)

    def _apply_routes(self, wanted: dict[str, int], *, request: dict[str, int], publish_ack: bool) -> None:
        """Validate every route first and apply all or none; acknowledge once the old sources are drained."""
        with self._route_lock:
            try:
                resolved = {slot: self._resolve(slot, number) for slot, number in wanted.items()}
            except RouteError as exc:
                self.report_error(exc.code, f"CONTROL_ENTRADA refused, previous routes kept: {exc}")
                if publish_ack:
                    self._publish_ack(False, request, str(exc))
                return
            changed = [slot for slot, number in wanted.items()
                       if slot not in self._routes or self._routes[slot] != number]
            fresh = {slot: self._make_reader(self._inputs[slot], key, wanted[slot])
                     for slot in changed if (key := resolved[slot]) is not None}
            for slot in changed:
                old = self._readers.pop(slot, None)
                if old is not None:
                    self._close_reader(old, drain=True)
                self._routes[slot] = wanted[slot]
                if slot in fresh:
                    self._readers[slot] = fresh[slot]
            if changed and self._running:
                routes = dict(self._routes)
                with self.lock:
                    self._call_safely("route_change", lambda: self.on_route_change(routes))
            if publish_ack:
                self._publish_ack(True, request, "")
            if self._running:
                for reader in fresh.values():
                    reader.gate.set()

    def _resolve(self, slot: str, number: int) -> str | None:
        if number == IGNORE:
            return None
        table = self.context.slot_table
        if table is None:
            raise RouteError(f"input {slot}: slot {number} cannot be resolved: this module has no slot table",
                             BusErrorCode.ROUTE_UNKNOWN_SLOT)
        return table.resolve(number, type_name(self._inputs[slot].type))

    def _publish_ack(self, accepted: bool, request: dict[str, int], reason: str) -> None:
        if self._ack_pub is not None:
            self._ack_pub.publish(RouteAck(module=self.module, accepted=accepted, routes=dict(self._routes),
                                           request=request, reason=reason, restart_count=self.restart_count))

    # ---------------------------------------------------------------- schema query

    def _answer_schema(self, query: zenoh.Query) -> None:
        doc = {
            "module": self.module, "robot": self.robot, "class": type_name(type(self)),
            "slots": {name: spec.describe() for name, spec in {**self._inputs, **self._outputs}.items()},
            "control": None if self.control is None else {
                "slot": self.control.slot, "type": type_name(self.control.type), "routes": self.control.routes},
            "routes": self._routes,
        }
        query.reply(query.key_expr, json.dumps(doc))

    # ---------------------------------------------------------------- process entry

    @classmethod
    def main(cls, argv: list[str] | None = None) -> int:
        """Entry point of ``python -m modules.<name>``: returns the process exit code."""
        logging.basicConfig(level=os.environ.get("CROMAT_LOG", "INFO"),
                            format="%(asctime)s %(name)s %(levelname)s %(message)s")
        context = load_context(argv, f"python -m {cls.__module__}", cls.name)
        try:
            module = cls(context)
        except Exception as exc:
            logging.getLogger(f"cromat.{context.module}").error("cannot start: %s", exc)
            return 2
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: module.request_stop())
        try:
            module.run()
        except SessionError as exc:
            module.log.error("%s", exc)
            return 2
        return 0


class _NoLock:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *_: object) -> None:
        return None


def _is_range_error(message: str) -> bool:
    return any(op in message for op in (">=", "<=", "` >", "` <", "length"))
