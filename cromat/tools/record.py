"""``cromat record``: write what a robot's bus carries to MCAP files (Foxglove, the ``mcap`` CLI).

Every key selected gets a channel with its struct's JSON Schema; each sample is written with the router's
timestamp, as JSON converted from the msgpack on the bus (see :mod:`cromat.tools.mcapfmt`). Samples wait in a
Zenoh FIFO per subscription (no Python callback per sample) and are written by its thread. Files split by size
or duration (``NAME_000.mcap``, ``NAME_001.mcap``...). At the end a summary: messages and bytes per channel,
and what was dropped (samples of safe state slots missed on the bus, data that were not msgpack).
"""

from __future__ import annotations

import argparse
import heapq
import json
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import msgspec
import zenoh
import zenoh.ext

from bbcs import forward_stop_signals
from cromat.tools import keyexpr, mcapfmt
from cromat.tools.catalog import Catalog, discover, struct_type
from cromat.tools.connection import ToolError, add_connection_options, config_from, connect
from cromat.tools.extras import require
from cromat.tools.progress import StatusLine

REORDER_S = 1.0
"""Each message waits this long (wall time) before it is written, so the file is in log-time order: the
subscriptions' threads hand samples over out of order (measured: up to 189 ms back across channels)."""
START_HOLD_S = 2.0
"""Nothing is written in the first seconds: the publishers' caches (last values of safe states, the RAL's last
GRI events, with their own older stamps) are still answering, and go first."""
GRI_EVENT_TYPE = "bbcs.contracts.gri:GriEvent"
"""Logged at their own ``stamp``: the RAL's cached events reach a late recorder with the time they arrive."""

FIFO_SAMPLES = 100_000
"""Samples a subscription buffers for its writer thread; when full, Zenoh back-pressures reliable publishers
(and best-effort ones drop), as for any slow subscriber: memory stays bounded."""


@dataclass
class ChannelStats:
    messages: int = 0
    bytes: int = 0
    """Bytes on the bus (msgpack)."""
    invalid: int = 0
    """Messages that did not validate against the slot's struct (recorded as they decoded)."""
    late: int = 0
    """Messages written after a later one (they came more than ``REORDER_S`` after it)."""


@dataclass
class Summary:
    files: list[str] = field(default_factory=list)
    channels: dict[str, ChannelStats] = field(default_factory=dict)
    missed: int = 0
    """Samples that safe state publishers sent and this recording never got (Zenoh's sample-miss detection)."""
    dropped_undecodable: int = 0
    started: float = 0.0
    ended: float = 0.0

    @property
    def messages(self) -> int:
        return sum(c.messages for c in self.channels.values())

    @property
    def late(self) -> int:
        return sum(c.late for c in self.channels.values())

    @property
    def bytes(self) -> int:
        return sum(c.bytes for c in self.channels.values())

    def lines(self) -> list[str]:
        span = max(self.ended - self.started, 1e-9)
        out = [f"recorded {self.messages} messages, {self.bytes} bytes from the bus in {span:.1f} s "
               f"into {len(self.files)} file(s): {', '.join(self.files)}",
               f"dropped: {self.missed} (missed on the bus), {self.dropped_undecodable} (not msgpack); "
               f"{self.late} written out of log-time order (came over {REORDER_S:g} s late)",
               f"{'channel':<42} {'messages':>9} {'bytes':>11} {'invalid':>8}"]
        for key, c in sorted(self.channels.items()):
            out.append(f"{key:<42} {c.messages:>9} {c.bytes:>11} {c.invalid:>8}")
        return out

    def as_dict(self) -> dict[str, Any]:
        return {"files": self.files, "messages": self.messages, "bytes": self.bytes, "late": self.late,
                "missed": self.missed, "dropped_undecodable": self.dropped_undecodable,
                "channels": {k: msgspec.structs.asdict(c) if isinstance(c, msgspec.Struct) else vars(c)
                             for k, c in self.channels.items()}}


class _Channel:
    __slots__ = ("id", "typed", "stats", "own_stamp")

    def __init__(self, channel_id: int, typed: Callable[[bytes], Any] | None, stats: ChannelStats,
                 own_stamp: bool = False) -> None:
        self.id = channel_id
        self.typed = typed
        self.stats = stats
        self.own_stamp = own_stamp
        """Messages logged at their own ``stamp`` field (GRI events), not the router's."""


class McapSink:
    """One MCAP file at a time, channels registered on first use; ``rotate()`` starts the next file."""

    def __init__(self, base: Path, catalog: Catalog, *, split: bool, compression: str = "zstd",
                 meta: dict[str, str] | None = None) -> None:
        self.base = base
        self.catalog = catalog
        self.split = split
        self.compression = compression
        self.meta = meta or {}
        self.summary = Summary()
        self.file_index = 0
        self._stream: Any = None
        self._writer: Any = None
        self._channels: dict[str, _Channel] = {}
        self.file_bytes = 0
        self.file_started = 0.0
        self._pending: list[tuple[int, int, float, str, bytes, str]] = []
        """Heap of (log time, arrival number, arrival, key, payload, encoding) waiting ``REORDER_S``."""
        self._arrivals = 0
        self._last_written = 0
        self.reorder_s = REORDER_S
        self._hold_until = time.monotonic() + START_HOLD_S
        self._open()

    def _path(self) -> Path:
        if not self.split:
            return self.base
        return self.base.with_name(f"{self.base.stem}_{self.file_index:03d}{self.base.suffix or '.mcap'}")

    def _open(self) -> None:
        path = self._path()
        path.parent.mkdir(parents=True, exist_ok=True)
        self._stream = open(path, "wb")  # noqa: SIM115 (closed in _close)
        from mcap.writer import CompressionType, Writer  # the tools extra (main() checks it is installed)

        kind = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        self._writer = Writer(self._stream, compression=kind[self.compression])
        self._writer.start(profile=mcapfmt.PROFILE, library="cromat record")
        self._writer.add_metadata("cromat.recording", {**self.meta, "file_index": str(self.file_index),
                                                        "started_ns": str(time.time_ns())})
        # what the bus said of itself, for a replay to say it again (cromat.tools.replay.LiveRobot)
        self._writer.add_metadata(mcapfmt.META_BUS, {
            "schemas": json.dumps(self.catalog.docs),
            "routes": msgspec.json.encode(self.catalog.route_lists).decode()})
        self._channels = {}
        self.file_bytes = 0
        self.file_started = time.monotonic()
        self.summary.files.append(str(path))

    def _close(self) -> None:
        if self._writer is not None:
            self.flush(everything=True)
            self._writer.finish()
            self._stream.close()
            self._writer = None

    def rotate(self) -> None:
        self._close()
        self.file_index += 1
        self._open()

    def close(self) -> None:
        self._close()

    def _channel(self, key: str, encoding: str) -> _Channel:
        info = self.catalog.info(key, encoding)
        tname = info.type
        typ = struct_type(tname)
        schema = mcapfmt.inline_refs(info.schema)
        assert self._writer is not None
        schema_id = self._writer.register_schema(name=tname or key, encoding=mcapfmt.SCHEMA_ENCODING,
                                                 data=json.dumps(schema).encode())
        channel_id = self._writer.register_channel(
            topic=key, message_encoding=mcapfmt.MESSAGE_ENCODING, schema_id=schema_id,
            metadata={mcapfmt.META_KEY: key, mcapfmt.META_TYPE: tname, mcapfmt.META_KIND: info.kind,
                      mcapfmt.META_SAFETY: info.safety, mcapfmt.META_BUS_ENCODING: encoding})
        stats = self.summary.channels.setdefault(key, ChannelStats())
        ch = self._channels[key] = _Channel(channel_id, msgspec.msgpack.Decoder(typ).decode if typ else None, stats,
                                            own_stamp=tname == GRI_EVENT_TYPE)
        return ch

    def write(self, key: str, payload: bytes, stamp_ns: int, encoding: str = "") -> None:
        """Queue one sample; it is written once it has waited ``reorder_s`` (:meth:`flush`), in log-time order."""
        if (ch := self._channels.get(key)) is None:
            ch = self._channel(key, encoding)
        if ch.own_stamp and ch.typed is not None:
            try:
                stamp_ns = int(ch.typed(payload).stamp * 1e9)
            except (msgspec.MsgspecError, AttributeError):
                pass
        self._arrivals += 1
        heapq.heappush(self._pending, (stamp_ns, self._arrivals, time.monotonic(), key, payload, encoding))
        if not self.reorder_s:
            self._hold_until = 0.0
            self.flush(everything=True)

    def flush(self, everything: bool = False) -> None:
        """Write the queued samples that have waited long enough (all of them with ``everything``), oldest log
        time first."""
        now = time.monotonic()
        if not everything and now < self._hold_until:
            return
        due = now - self.reorder_s
        while self._pending and (everything or self._pending[0][2] <= due):
            stamp_ns, _, _, key, payload, encoding = heapq.heappop(self._pending)
            self._write(key, payload, stamp_ns, encoding)

    def _write(self, key: str, payload: bytes, stamp_ns: int, encoding: str) -> None:
        ch = self._channels.get(key) or self._channel(key, encoding)
        if stamp_ns < self._last_written:
            ch.stats.late += 1
        self._last_written = max(self._last_written, stamp_ns)
        try:
            data = msgspec.json.encode(ch.typed(payload)) if ch.typed is not None else None
        except msgspec.ValidationError:
            ch.stats.invalid += 1
            data = None
        except msgspec.DecodeError:
            data = None
        if data is None:
            try:
                data = msgspec.json.encode(msgspec.msgpack.decode(payload))
            except (msgspec.DecodeError, TypeError, ValueError):
                self.summary.dropped_undecodable += 1
                return
        assert self._writer is not None
        self._writer.add_message(ch.id, log_time=stamp_ns, data=data, publish_time=stamp_ns,
                                 sequence=ch.stats.messages)
        ch.stats.messages += 1
        ch.stats.bytes += len(payload)
        self.file_bytes += len(data)


class Recorder:
    """Subscribes to ``selections``; each subscription's samples wait in a Zenoh FIFO (handed over without the
    GIL, no Python callback per sample) drained by its own thread into one :class:`McapSink`."""

    def __init__(self, session: zenoh.Session, sink: McapSink, selections: list[str], *,
                 split_bytes: int = 0, split_s: float = 0.0, fifo: int = FIFO_SAMPLES) -> None:
        self.sink = sink
        self.split_bytes = split_bytes
        self.split_s = split_s
        self.received = 0
        self.lock = self._lock = threading.Lock()
        self.sink.summary.started = time.time()
        # advanced subscribers: the last value of every safe state slot (cached by its publisher) is recorded too
        self._subs = [zenoh.ext.declare_advanced_subscriber(
            session, sel, zenoh.handlers.FifoChannel(fifo),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True)) for sel in selections]
        self._listeners = [sub.sample_miss_listener(self._on_miss) for sub in self._subs]
        self._threads = [threading.Thread(target=self._drain, args=(sub,), name=f"record.{i}", daemon=True)
                         for i, sub in enumerate(self._subs)]
        for t in self._threads:
            t.start()

    def _on_miss(self, miss: Any) -> None:
        self.sink.summary.missed += int(miss.nb)

    def _drain(self, sub: Any) -> None:
        sink = self.sink
        try:
            for sample in sub:
                if sample.kind != zenoh.SampleKind.PUT:
                    continue
                ts = sample.timestamp
                stamp = int(ts.get_time_as_ntp64().as_nanos()) if ts is not None else time.time_ns()
                key, payload = str(sample.key_expr), sample.payload.to_bytes()
                with self._lock:
                    self.received += 1
                    sink.write(key, payload, stamp, str(sample.encoding))
                    sink.flush()
                    if (self.split_bytes and sink.file_bytes >= self.split_bytes) or (
                            self.split_s and time.monotonic() - sink.file_started >= self.split_s):
                        sink.rotate()
        except zenoh.ZError:
            return  # the channel closed: the subscriber was undeclared

    def stop(self) -> Summary:
        """Undeclare, write what is queued, finish the file(s); the summary of the whole recording."""
        for listener in self._listeners:
            listener.undeclare()
        self._listeners = []
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:  # noqa: BLE001 (an undeclare racing the drain thread; the session close ends it)
                pass
        self._subs = []
        for t in self._threads:
            t.join(10)
        with self._lock:
            self.sink.close()
        self.sink.summary.ended = time.time()
        return self.sink.summary


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cromat record", description="Record a robot's bus to MCAP.")
    add_connection_options(p)
    p.add_argument("-o", "--output", required=True, help="MCAP file to write (NAME_000.mcap... when splitting)")
    p.add_argument("--robot", default="*", help="robot to record (default every robot behind the router)")
    p.add_argument("--select", action="append", metavar="KEYEXPR",
                   help="key expression to record (repeatable); default: every slot of the robot plus its GRI "
                        "state/events, manager state, route acks and heartbeats")
    p.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: until Ctrl-C)")
    p.add_argument("--count", type=int, default=0, help="stop after N messages (0: no limit)")
    p.add_argument("--split-size", type=float, default=0.0, metavar="MB", help="start a new file every MB")
    p.add_argument("--split-duration", type=float, default=0.0, metavar="S", help="start a new file every S s")
    p.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    p.add_argument("--summary-json", metavar="FILE", help="also write the summary as JSON")
    p.add_argument("--verify", action="store_true", help="at the end, check every file written: CRCs, indexes "
                   "and summary statistics (cromat.tools.mcap_check; the mcap CLI's `doctor` is not available)")
    return p


def run(args: argparse.Namespace, out: TextIO) -> int:
    selections = [keyexpr.expand(s) for s in args.select] if args.select else keyexpr.everything(args.robot)
    for sel in selections:
        try:
            zenoh.KeyExpr(sel)
        except Exception as exc:
            raise ToolError(f"{sel!r} is not a key expression: {exc}") from None
    session = connect(args)
    stop = threading.Event()
    restore_signals = forward_stop_signals(lambda _signum: stop.set())  # never a lock in a signal handler
    try:
        catalog = discover(session, args.robot, args.timeout, config_from(args))
        split = bool(args.split_size or args.split_duration)
        sink = McapSink(Path(args.output), catalog, split=split, compression=args.compression,
                        meta={"robot": args.robot, "selections": " ".join(selections),
                              "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
        rec = Recorder(session, sink, selections, split_bytes=int(args.split_size * 1e6),
                       split_s=args.split_duration)
        status = StatusLine()
        t0 = time.monotonic()
        print(f"recording {', '.join(selections)} to {args.output}", file=sys.stderr)
        while not stop.is_set():
            elapsed = time.monotonic() - t0
            if (args.duration and elapsed >= args.duration) or (args.count and rec.received >= args.count):
                break
            s = sink.summary
            with rec.lock:
                sink.flush()
            status.show(f"recording {elapsed:7.1f} s  {rec.received} msgs  {s.bytes / 1e6:.2f} MB  "
                        f"{len(s.channels)} channels  dropped {s.missed + s.dropped_undecodable}  "
                        f"file {sink.file_index}")
            stop.wait(0.1)
        status.done()
        summary = rec.stop()
    finally:
        restore_signals()
        session.close()
    print("\n".join(summary.lines()), file=out)
    if args.summary_json:
        Path(args.summary_json).write_text(json.dumps(summary.as_dict(), indent=2))
    if args.verify:
        from cromat.tools.mcap_check import McapCheckError, check_mcap

        try:
            for path in summary.files:
                print(f"verified {check_mcap(path).line()}", file=out)
        except McapCheckError as exc:
            print(f"cromat record: verification failed: {exc}", file=sys.stderr)
            return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if (missing := require("record")) is not None:
        print(missing, file=sys.stderr)
        return 2
    try:
        return run(args, sys.stdout)
    except ToolError as exc:
        print(f"cromat record: {exc}", file=sys.stderr)
        return exc.code


if __name__ == "__main__":
    raise SystemExit(main())
