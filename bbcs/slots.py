"""Slots: direction × state|stream × safe|unsafe × one msgspec Struct type, and their delivery on Zenoh.

| slot          | publisher                                  | subscriber side                                   |
|---------------|--------------------------------------------|---------------------------------------------------|
| unsafe state  | best effort, congestion DROP               | newest value only (kept by the module's loop)     |
| safe state    | reliable, BLOCK, last value cached for late | every value in order in a bounded FIFO; a late     |
|               | joiners (zenoh.ext AdvancedPublisher)      | joiner first gets the cached last value            |
| safe stream   | reliable, BLOCK                            | every value in order in a bounded FIFO            |

*Why zenoh.ext for safe state*: the advanced publisher's cache and the advanced subscriber's history give a late
joiner the last value with sequence numbers, so a value is never handled twice even when the history reply and a
live sample race; with heartbeats it also recovers values lost while the robot router restarted. A hand-made
queryable would need all of that written again.

*The safe queue*: each safe input may have ``queue`` samples (default 1024) waiting for the module's loop. When
that many wait, the input's Zenoh callback blocks and Zenoh stops reading that link: the reliable, BLOCK
publisher is slowed down, nothing is dropped. The publisher reports it: a ``put`` that blocks longer than
``BACKPRESSURE_S`` is logged with the slot's name and counted in :attr:`Publisher.backpressure_events`.

*The outbox* (``OutputSlot(..., outbox=N)``): for reports a safety process sends beside its real work (the DSP
process's error and sent streams, issue 32). A safe put can block for as long as a consumer is slow; a thread that
must keep a heartbeat or an abort path going cannot wait for that. With an outbox, ``publish`` encodes and hands the
bytes to a queue of ``N`` that a thread of the publisher's own puts, in order: the caller never blocks. A value that
finds the outbox full is dropped and counted (:attr:`Publisher.dropped`); the owner reports the count, once, not
once per value (:meth:`Publisher.take_dropped`).
"""

from __future__ import annotations

import collections
import datetime
import enum
import logging
import threading
import time
import weakref
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import msgspec
import zenoh
import zenoh.ext

from bbcs import keys
from bbcs.codec import Codec, codec_for, encode
from bbcs.errors import SlotError
from bbcs.wire import encoding_for

log = logging.getLogger("bbcs.slots")

T = TypeVar("T", bound=msgspec.Struct)

DEFAULT_SAFE_QUEUE = 1024
PRIORITIES = ("REAL_TIME", "INTERACTIVE_HIGH", "INTERACTIVE_LOW", "DATA_HIGH", "DATA", "DATA_LOW", "BACKGROUND")
"""Zenoh's priorities, highest first (``SlotSpec.priority`` takes them in lower case)."""
"""Samples a safe input buffers before Zenoh back-pressures its publisher."""
BACKPRESSURE_S = 0.05
"""A safe ``put`` blocked longer than this is reported as consumer back-pressure."""
SAFE_STATE_HEARTBEAT_S = 0.5
"""Sporadic heartbeat period of safe state publishers (lets subscribers detect and recover a lost last value)."""
REPLAY_QUERY_S = 1.0
"""How often a replaying stream's subscriber (:func:`declare_replaying_subscriber`) asks the publisher's cache for
what it has not received: after a cut heals, what was published meanwhile arrives within about this time. Periodic
queries, not the publisher's heartbeats: measured, a sample published at the instant the link came back stalled a
heartbeat-driven recovery until the next sample (a tail event could wait forever)."""


class Direction(enum.StrEnum):
    IN = "in"
    OUT = "out"


class Kind(enum.StrEnum):
    STATE = "state"
    STREAM = "stream"


class Safety(enum.StrEnum):
    SAFE = "safe"
    UNSAFE = "unsafe"


@dataclass(frozen=True)
class SlotSpec(Generic[T]):
    """What a module declares about one slot. Names are lower-case key chunks (``datos``, ``control_modo``)."""

    name: str
    type: type[T]
    direction: Direction
    kind: Kind = Kind.STATE
    safety: Safety = Safety.SAFE
    queue: int = DEFAULT_SAFE_QUEUE
    peer: str | None = None
    """Another module's slot this one is bound to, ``module`` (same slot name) or ``module/slot``: an input
    reads that output (e.g. ``dsp/telemetry``); an output writes into that module's input, a mailbox (e.g.
    ``dsp/commands``). None: the slot lives under this module's own key."""
    priority: str | None = None
    """An output's Zenoh priority, by name (``real_time``, ``interactive_high``, ``interactive_low``, ``data_high``,
    ``data``, ``data_low``, ``background``): what a link sends first when it is busy. None: Zenoh's default (data).
    The DSP's commands (abort among them) and its telemetry go ahead of bulk and perception data (issue 32)."""
    express: bool = False
    """Send at once instead of batching with what follows (Zenoh's express): for rare, urgent outputs."""
    outbox: int = 0
    """An output's outbox (module docstring): 0, put on the caller's thread; N, at most N values wait for the
    publisher's own thread and one more is dropped and counted, so the caller never blocks."""

    def __post_init__(self) -> None:
        keys.validate_name(self.name, "slot name")
        if self.peer is not None:
            module, _, slot = self.peer.partition("/")
            keys.validate_name(module, "peer module name")
            keys.validate_name(slot or self.name, "peer slot name")
        if not (isinstance(self.type, type) and issubclass(self.type, msgspec.Struct)):
            raise SlotError(f"slot {self.name!r}: type must be a msgspec.Struct subclass, got {self.type!r}")
        if self.kind is Kind.STREAM and self.safety is Safety.UNSAFE:
            raise SlotError(f"slot {self.name!r}: a stream is always safe (every message, in order)")
        if self.queue < 1:
            raise SlotError(f"slot {self.name!r}: queue bound must be at least 1")
        if self.outbox < 0 or (self.outbox and self.direction is not Direction.OUT):
            raise SlotError(f"slot {self.name!r}: an outbox is a bound >= 1 on an output slot")
        if self.priority is not None and self.priority.upper() not in PRIORITIES:
            raise SlotError(f"slot {self.name!r}: priority {self.priority!r} is not one of "
                            f"{', '.join(p.lower() for p in PRIORITIES)}")

    @property
    def codec(self) -> Codec[T]:
        return codec_for(self.type)

    def key(self, robot: str, module: str) -> str:
        """Where this slot lives for ``module`` of ``robot`` (the peer's key when it has one)."""
        if self.peer is None:
            return keys.slot_key(robot, module, self.name)
        peer_module, _, peer_slot = self.peer.partition("/")
        return keys.slot_key(robot, peer_module, peer_slot or self.name)

    def describe(self) -> dict[str, Any]:
        """What the schema query returns for this slot."""
        return {
            "direction": str(self.direction), "kind": str(self.kind), "safety": str(self.safety),
            **({"peer": self.peer} if self.peer else {}),
            "type": self.codec.name, "schema": msgspec.json.schema(self.type),
            **({"queue": self.queue} if self.direction is Direction.IN and self.safety is Safety.SAFE else {}),
        }


def InputSlot(name: str, type: type[T], *, kind: Kind = Kind.STATE, safety: Safety = Safety.SAFE,  # noqa: N802
              queue: int = DEFAULT_SAFE_QUEUE, peer: str | None = None) -> SlotSpec[T]:
    """Declare an input slot (``peer``: always read that module's output slot of the same name)."""
    return SlotSpec(name, type, Direction.IN, Kind(kind), Safety(safety), queue, peer)


def OutputSlot(name: str, type: type[T], *, kind: Kind = Kind.STATE,  # noqa: N802
               safety: Safety = Safety.SAFE, peer: str | None = None, priority: str | None = None,
               express: bool = False, outbox: int = 0) -> SlotSpec[T]:
    """Declare an output slot (``peer``: write into that module's input slot of the same name; ``priority``,
    ``express``, ``outbox``: :class:`SlotSpec`)."""
    return SlotSpec(name, type, Direction.OUT, Kind(kind), Safety(safety), peer=peer, priority=priority,
                    express=express, outbox=outbox)


class _BlockWatch:
    """Notices safe ``put``s blocked longer than ``BACKPRESSURE_S``: one daemon thread per process looks at the
    publishers every half ``BACKPRESSURE_S`` while a put is in progress (every ``2 * BACKPRESSURE_S`` otherwise).
    Cheaper than reading the clock around every put: here a clock read is a system call, and two of them cost more
    than the rest of ``publish()`` besides encoding and the put."""

    def __init__(self) -> None:
        self._publishers: weakref.WeakSet[Publisher[Any]] = weakref.WeakSet()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._looks: weakref.WeakKeyDictionary[Publisher[Any], tuple[int, int]] = weakref.WeakKeyDictionary()

    def add(self, pub: Publisher[Any]) -> None:
        with self._lock:
            self._publishers.add(pub)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="bbcs-backpressure", daemon=True)
                self._thread.start()

    def discard(self, pub: Publisher[Any]) -> None:
        with self._lock:
            self._publishers.discard(pub)

    def _run(self) -> None:
        while True:  # every 100 ms while no put is seen in progress, every 25 ms once one is (ten wakes a second idle)
            time.sleep(BACKPRESSURE_S / 2 if self._looks else 2 * BACKPRESSURE_S)
            with self._lock:
                publishers = list(self._publishers)
            self.look(publishers)

    def look(self, publishers: Iterable[Publisher[Any]]) -> None:
        """One look: a put seen in progress, the same one (same count of puts done), at three looks in a row has
        been blocked at least ``BACKPRESSURE_S``; each blocked put is reported once."""
        for pub in publishers:
            done = pub.published
            if not pub._putting:
                self._looks.pop(pub, None)
                continue
            prev_done, seen = self._looks.get(pub, (done, 0))
            seen = seen + 1 if prev_done == done else 1
            self._looks[pub] = (done, seen)
            if seen == 3:
                pub.backpressure_events += 1
                log.warning("slot %s: a put blocked over %.0f ms: a consumer's safe queue is full (back-pressure)",
                            pub.key, BACKPRESSURE_S * 1000)


_block_watch = _BlockWatch()


class Publisher(Generic[T]):
    """Publishes one slot's structs with the QoS its kind and safety call for."""

    def __init__(self, session: zenoh.Session, key: str, spec: SlotSpec[T], *, replay: int = 0) -> None:
        """``replay``: for a safe stream, keep its last ``replay`` samples, so that a subscriber with recovery
        (:func:`declare_replaying_subscriber`) gets what it missed while a link was cut (events that cross the
        fleet mesh). 0: a plain reliable publisher, nothing kept."""
        if replay and (spec.kind is not Kind.STREAM or spec.safety is not Safety.SAFE):
            raise SlotError(f"slot {spec.name!r}: replay is for safe streams (a state slot keeps its last value)")
        self.spec = spec
        self.key = key
        self.published = 0
        self.backpressure_events = 0
        self._closed = False
        encoding = encoding_for(spec.type)
        qos: dict[str, Any] = {"express": True} if spec.express else {}
        if spec.priority is not None:
            qos["priority"] = getattr(zenoh.Priority, spec.priority.upper())
        if spec.safety is Safety.UNSAFE:
            self._pub: Any = session.declare_publisher(
                key, encoding=encoding, reliability=zenoh.Reliability.BEST_EFFORT,
                congestion_control=zenoh.CongestionControl.DROP, **qos)
        elif spec.kind is Kind.STATE:
            self._pub = zenoh.ext.declare_advanced_publisher(
                session, key, encoding=encoding, reliability=zenoh.Reliability.RELIABLE, **qos,
                congestion_control=zenoh.CongestionControl.BLOCK,
                cache=zenoh.ext.CacheConfig(1),
                sample_miss_detection=zenoh.ext.MissDetectionConfig(
                    heartbeat=None, sporadic_heartbeat=SAFE_STATE_HEARTBEAT_S),
                publisher_detection=True)
        elif replay:
            self._pub = zenoh.ext.declare_advanced_publisher(
                session, key, encoding=encoding, reliability=zenoh.Reliability.RELIABLE, **qos,
                congestion_control=zenoh.CongestionControl.BLOCK,
                cache=zenoh.ext.CacheConfig(replay),
                sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=None),
                publisher_detection=True)
        else:
            self._pub = session.declare_publisher(
                key, encoding=encoding, reliability=zenoh.Reliability.RELIABLE,
                congestion_control=zenoh.CongestionControl.BLOCK, **qos)
        self._type = spec.type
        self._put = self._pub.put
        self._putting = False
        if spec.safety is Safety.SAFE:
            _block_watch.add(self)
        self.dropped = 0
        """Values an outbox had no room for (module docstring)."""
        self._reported_drops = 0
        self._outbox: collections.deque[bytes] | None = None
        if spec.outbox:
            self._outbox = collections.deque()
            self._outbox_ready = threading.Condition(threading.Lock())
            self._outbox_thread = threading.Thread(target=self._send_outbox, name=f"outbox-{spec.name}",
                                                   daemon=True)
            self._outbox_thread.start()

    def publish(self, value: T) -> None:
        """Encode and put ``value``. Types are checked where they are cheap: the struct class must match."""
        if type(value) is not self._type:
            raise SlotError(f"slot {self.spec.name!r} carries {self.spec.type.__name__}, "
                            f"not {type(value).__name__}")
        if self._outbox is not None:
            self._post(encode(value))
            return
        self._putting = True  # what the back-pressure watch looks at (a safe put can block)
        self._put(encode(value))
        self._putting = False
        self.published += 1

    def publish_raw(self, payload: bytes) -> None:
        """Put bytes already encoded (bench and bridging code); no type check."""
        if self._outbox is not None:
            self._post(payload)
            return
        self._putting = True
        self._pub.put(payload)
        self._putting = False
        self.published += 1

    def _post(self, payload: bytes) -> None:
        """Into the outbox, never waiting: dropped and counted when ``spec.outbox`` values already wait."""
        box = self._outbox
        assert box is not None
        with self._outbox_ready:
            if len(box) >= self.spec.outbox or self._closed:
                self.dropped += 1
                return
            box.append(payload)
            self._outbox_ready.notify()

    def _send_outbox(self) -> None:
        box = self._outbox
        assert box is not None
        while True:
            with self._outbox_ready:
                while not box and not self._closed:
                    self._outbox_ready.wait()
                if self._closed:
                    return
                payload = box[0]
            self._putting = True
            try:
                self._put(payload)
            except Exception as exc:  # the session is closing: what waits is lost with it
                log.debug("slot %s: outbox put failed: %s", self.key, exc)
            self._putting = False
            with self._outbox_ready:
                if box:
                    box.popleft()
            self.published += 1

    def waiting(self) -> int:
        """Values in the outbox not yet put (0 without one)."""
        return len(self._outbox) if self._outbox is not None else 0

    def take_dropped(self) -> int:
        """Values dropped since the last call: what the owner reports once, as a count."""
        n, self._reported_drops = self.dropped - self._reported_drops, self.dropped
        return n

    def withdraw(self) -> None:
        """Delete the slot's value: a state publisher's cache then answers late joiners with an empty payload,
        which a bbcs input treats as no value (bbcs.module), as it does the live delete."""
        self._pub.delete()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            _block_watch.discard(self)
            if self._outbox is not None:
                with self._outbox_ready:
                    self._outbox_ready.notify_all()
                self._outbox_thread.join(1.0)  # one stuck in a blocked put is a daemon: not waited for longer
            self._pub.undeclare()


def declare_replaying_subscriber(session: zenoh.Session, key: str, handler: Callable[[zenoh.Sample], None]) -> Any:
    """A subscriber of a replaying stream (``Publisher(replay=N)``): live samples, plus those it missed while a
    link was cut, asked from the publisher's cache every ``REPLAY_QUERY_S``; in order, each once. No history: a
    subscriber that joins late gets nothing from before it joined."""
    return zenoh.ext.declare_advanced_subscriber(
        session, key, handler, subscriber_detection=True,
        recovery=zenoh.ext.RecoveryConfig(periodic_queries=datetime.timedelta(seconds=REPLAY_QUERY_S)))


def declare_reader(session: zenoh.Session, key: str, spec: SlotSpec[Any],
                   handler: Callable[[zenoh.Sample], None] | zenoh.handlers.FifoChannel[zenoh.Sample]) -> Any:
    """Declare the Zenoh subscriber behind an input slot: ``handler`` is a callback (which only enqueues) or a
    Zenoh FIFO channel the module's loop drains.

    Newest-only (unsafe) and the bounded in-order queue (safe) are kept by the module's loop (bbcs.module);
    safe state → AdvancedSubscriber with history of the last value (late joiners) and recovery.
    """
    if spec.safety is Safety.UNSAFE or spec.kind is Kind.STREAM:
        return session.declare_subscriber(key, handler)
    return zenoh.ext.declare_advanced_subscriber(
        session, key, handler,
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
        recovery=zenoh.ext.RecoveryConfig(periodic_queries=None, heartbeat=True),
        subscriber_detection=True)
