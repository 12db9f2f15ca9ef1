"""``cromat bag``: look into MCAP recordings, as ``ros2 bag info`` and the ``mcap`` CLI do.

| command | what |
| --- | --- |
| ``info FILE...``   | channels, types, message counts, rates, duration, size, compression |
| ``filter IN -o OUT`` | some keys (``--select``), a robot (``--robot``), a time range into a new MCAP file |
| ``cat FILE...``    | the messages decoded, one JSON object per line |
| ``export FILE... -o OUT.csv`` | the selected messages as CSV, one column per field (``a.b.c``), for plots |

Reads what ``cromat record`` writes (JSON messages, JSON Schemas, ``cromat.*`` channel metadata) and what
``cromat foxglove --mcap`` writes (the same, plus the derived Foxglove channels: protobuf, shown as base64 by
``cat`` and left out of ``export``, which takes JSON channels only). Times given to ``--start``/``--end`` are
seconds from the first message of the first file, or absolute seconds since the epoch (any value above 1e9).
Exit codes: 0 done, 1 nothing matched, 2 usage or an unreadable file.
"""

from __future__ import annotations

import argparse
import base64
import csv
import json
import os
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from cromat.tools import keyexpr, mcapfmt
from cromat.tools.extras import require

EPOCH_AFTER = 1e9
"""A ``--start``/``--end`` above this is seconds since the epoch; below, seconds from the recording's start."""


MIN_RATE_SPAN_NS = 500_000_000
"""A channel's rate is shown when its messages span this long (a burst of three in 65 µs is no rate)."""


class BagError(RuntimeError):
    """A file cannot be read or the options cannot work; the message says why."""


@dataclass
class ChannelInfo:
    topic: str
    type: str
    encoding: str
    messages: int = 0
    first_ns: int = 0
    last_ns: int = 0


@dataclass
class BagInfo:
    path: str
    size: int
    profile: str = ""
    library: str = ""
    compression: list[str] = field(default_factory=list)
    chunks: int = 0
    first_ns: int = 0
    last_ns: int = 0
    channels: list[ChannelInfo] = field(default_factory=list)

    @property
    def messages(self) -> int:
        return sum(c.messages for c in self.channels)

    @property
    def duration_s(self) -> float:
        return max(0.0, (self.last_ns - self.first_ns) / 1e9)

    def lines(self) -> list[str]:
        def when(ns: int) -> str:
            stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(ns / 1e9))
            return f"{stamp}.{ns % 1_000_000_000 // 1_000_000:03d} UTC"

        out = [f"file:        {self.path}",
               f"size:        {self.size / 1e6:.3f} MB ({self.size} bytes)",
               f"written by:  {self.library or '-'} (profile {self.profile or '-'})",
               f"compression: {', '.join(self.compression) or 'none'} ({self.chunks} chunks)",
               f"duration:    {self.duration_s:.3f} s",
               f"start:       {when(self.first_ns) if self.messages else '-'}",
               f"end:         {when(self.last_ns) if self.messages else '-'}",
               f"messages:    {self.messages} on {len(self.channels)} channels"]
        width = min(max((len(c.topic) for c in self.channels), default=5), 48)
        out.append(f"{'channel':<{width}} {'type':<28} {'encoding':<9} {'messages':>8} {'rate':>9}")
        for c in sorted(self.channels, key=lambda c: c.topic):
            rate = f"{(c.messages - 1) / ((c.last_ns - c.first_ns) / 1e9):.2f}Hz" \
                if c.messages > 2 and c.last_ns - c.first_ns >= MIN_RATE_SPAN_NS else "-"
            out.append(f"{c.topic:<{width}} {c.type.rpartition(':')[2][:28]:<28} {c.encoding:<9} {c.messages:>8} "
                       f"{rate:>9}")
        return out

    def as_dict(self) -> dict[str, Any]:
        return {"path": self.path, "size": self.size, "profile": self.profile, "library": self.library,
                "compression": self.compression, "chunks": self.chunks, "messages": self.messages,
                "start_ns": self.first_ns, "end_ns": self.last_ns, "duration_s": self.duration_s,
                "channels": [vars(c) for c in sorted(self.channels, key=lambda c: c.topic)]}


def _open_reader(f: Any) -> Any:
    from mcap.reader import make_reader

    return make_reader(f)


def bag_info(path: Path) -> BagInfo:
    """What ``info`` prints, from every record of the file (BagError naming the file if it cannot be read)."""
    try:
        return _bag_info(path)
    except BagError:
        raise
    except Exception as exc:  # the library's own errors: bad magic, a truncated record...
        raise BagError(f"{path}: not a readable MCAP file: {type(exc).__name__}: {exc}") from None


def _bag_info(path: Path) -> BagInfo:
    from mcap.records import Chunk, Header
    from mcap.stream_reader import StreamReader

    info = BagInfo(str(path), path.stat().st_size)
    compression: set[str] = set()
    with open(path, "rb") as f:
        for record in StreamReader(f, emit_chunks=True, validate_crcs=False).records:
            if isinstance(record, Header):
                info.profile, info.library = record.profile, record.library
            elif isinstance(record, Chunk):
                info.chunks += 1
                compression.add(record.compression or "none")
    info.compression = sorted(compression)
    channels: dict[int, ChannelInfo] = {}
    for schema, channel, message in _messages([path]):
        ch = channels.get(channel.id)
        if ch is None:
            tname = (channel.metadata or {}).get(mcapfmt.META_TYPE) or (schema.name if schema else "")
            ch = channels[channel.id] = ChannelInfo(channel.topic, tname, channel.message_encoding,
                                                    first_ns=message.log_time)
        ch.messages += 1
        ch.first_ns = min(ch.first_ns, message.log_time)
        ch.last_ns = max(ch.last_ns, message.log_time)
    with open(path, "rb") as f:  # channels without messages are channels too
        summary = _open_reader(f).get_summary()
    for cid, channel in (summary.channels.items() if summary else []):
        if cid not in channels:
            schema = summary.schemas.get(channel.schema_id)
            tname = (channel.metadata or {}).get(mcapfmt.META_TYPE) or (schema.name if schema else "")
            channels[cid] = ChannelInfo(channel.topic, tname, channel.message_encoding)
    info.channels = list(channels.values())
    with_data = [c for c in info.channels if c.messages]
    if with_data:
        info.first_ns = min(c.first_ns for c in with_data)
        info.last_ns = max(c.last_ns for c in with_data)
    return info


def _messages(files: list[Path]) -> Iterator[tuple[Any, Any, Any]]:
    for path in files:
        try:
            with open(path, "rb") as f:
                yield from _open_reader(f).iter_messages(log_time_order=False)
        except BagError:
            raise
        except Exception as exc:  # the library's own errors: bad magic, a truncated record...
            raise BagError(f"{path}: not a readable MCAP file: {type(exc).__name__}: {exc}") from None


@dataclass
class Selection:
    """Which messages: keys (key expressions), a robot, a log-time range (ns, inclusive)."""

    selects: list[str] = field(default_factory=list)
    robot: str = ""
    start_ns: int | None = None
    end_ns: int | None = None

    def channel(self, channel: Any) -> bool:
        key = (channel.metadata or {}).get(mcapfmt.META_KEY, channel.topic)
        if self.robot:
            parts = key.strip("/").split("/")
            robot = parts[1] if parts[0] == "cromat" and len(parts) > 1 else parts[0]
            if robot != self.robot:
                return False
        if self.selects:
            if not key.startswith("cromat/"):
                return any(s.strip("/") == key.strip("/") for s in self.selects)
            return any(keyexpr.intersects(keyexpr.expand(s), key) for s in self.selects if not s.startswith("/"))
        return True

    def time(self, log_time: int) -> bool:
        return (self.start_ns is None or log_time >= self.start_ns) and (self.end_ns is None or log_time <= self.end_ns)


def selection(args: argparse.Namespace, files: list[Path]) -> Selection:
    sel = Selection(list(args.select or []), args.robot or "")
    for s in sel.selects:
        if not s.startswith("/"):
            try:
                keyexpr.intersects(keyexpr.expand(s), "cromat/x/y/z")
            except Exception as exc:
                raise BagError(f"--select {s!r} is not a key expression: {exc}") from None
    if args.start is not None or args.end is not None:
        first = min((bag_info(p).first_ns for p in files), default=0)

        def at(seconds: float) -> int:
            return int(seconds * 1e9) if seconds > EPOCH_AFTER else first + int(seconds * 1e9)

        sel.start_ns = at(args.start) if args.start is not None else None
        sel.end_ns = at(args.end) if args.end is not None else None
        if sel.start_ns is not None and sel.end_ns is not None and sel.end_ns < sel.start_ns:
            raise BagError("--end is before --start")
    return sel


def cmd_info(args: argparse.Namespace, out: TextIO) -> int:
    for i, path in enumerate(args.files):
        info = bag_info(path)
        if args.json:
            print(json.dumps(info.as_dict()), file=out)
        else:
            print(("\n" if i else "") + "\n".join(info.lines()), file=out)
    return 0


def cmd_filter(args: argparse.Namespace, out: TextIO) -> int:
    from mcap.writer import CompressionType, Writer

    sel = selection(args, args.files)
    target = Path(args.output)
    if target.resolve() in {p.resolve() for p in args.files}:
        raise BagError("the output must not be one of the input files")
    kind = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
    tmp = target.with_name(target.name + ".part")
    written = 0
    with open(tmp, "wb") as stream:
        writer = Writer(stream, compression=kind[args.compression])
        writer.start(profile=mcapfmt.PROFILE, library="cromat bag filter")
        for path in args.files[:1]:  # the recording's own description, for replay (cromat.recording, cromat.bus)
            with open(path, "rb") as f:
                for record in _open_reader(f).iter_metadata():
                    writer.add_metadata(record.name, dict(record.metadata))
        schemas: dict[tuple[str, str, bytes], int] = {}
        channels: dict[tuple[str, str], int] = {}
        for schema, channel, message in _messages(args.files):
            if not sel.time(message.log_time) or not sel.channel(channel):
                continue
            skey = (schema.name, schema.encoding, bytes(schema.data)) if schema else ("", "", b"")
            if skey not in schemas:
                schemas[skey] = writer.register_schema(name=skey[0], encoding=skey[1], data=skey[2]) if schema else 0
            ckey = (channel.topic, json.dumps(channel.metadata or {}, sort_keys=True))
            if ckey not in channels:
                channels[ckey] = writer.register_channel(topic=channel.topic,
                                                         message_encoding=channel.message_encoding,
                                                         schema_id=schemas[skey], metadata=dict(channel.metadata or {}))
            writer.add_message(channels[ckey], log_time=message.log_time, data=message.data,
                               publish_time=message.publish_time, sequence=message.sequence)
            written += 1
        writer.finish()
    os.replace(tmp, target)
    print(f"wrote {written} messages on {len(channels)} channels to {target}", file=out)
    return 0 if written else 1


def _decoded(channel: Any, data: bytes) -> tuple[Any, str]:
    """A message as JSON-able data, and how it was given: ``json`` (parsed) or ``base64`` (any other encoding)."""
    if channel.message_encoding == mcapfmt.MESSAGE_ENCODING:
        try:
            return json.loads(data), "json"
        except ValueError:
            pass
    return base64.b64encode(data).decode(), "base64"


def cmd_cat(args: argparse.Namespace, out: TextIO) -> int:
    sel = selection(args, args.files)
    n = 0
    for schema, channel, message in _messages(args.files):
        if not sel.time(message.log_time) or not sel.channel(channel):
            continue
        value, how = _decoded(channel, message.data)
        tname = (channel.metadata or {}).get(mcapfmt.META_TYPE) or (schema.name if schema else "")
        rec = {"topic": channel.topic, "type": tname, "log_time": message.log_time / 1e9, "data": value}
        if how != "json":
            rec["encoding"] = f"{channel.message_encoding} as base64"
        out.write(json.dumps(rec, separators=(",", ":")) + "\n")
        n += 1
        if args.count and n >= args.count:
            break
    return 0 if n else 1


def flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    """Nested maps and lists as ``{"a.b.0": leaf}`` columns (a list's items by index)."""
    if isinstance(value, dict):
        out: dict[str, Any] = {}
        for k, v in value.items():
            out.update(flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    if isinstance(value, list):
        out = {}
        for i, v in enumerate(value):
            out.update(flatten(v, f"{prefix}.{i}" if prefix else str(i)))
        return out
    return {prefix or "value": value}


def cmd_export(args: argparse.Namespace, out: TextIO) -> int:
    sel = selection(args, args.files)
    fields = [f.strip() for f in args.fields.split(",") if f.strip()] if args.fields else []
    rows: list[dict[str, Any]] = []
    columns: dict[str, None] = {}
    skipped: set[str] = set()
    for _schema, channel, message in _messages(args.files):
        if not sel.time(message.log_time) or not sel.channel(channel):
            continue
        value, how = _decoded(channel, message.data)
        if how != "json":
            skipped.add(channel.topic)
            continue
        flat = flatten(value)
        if fields:
            flat = {f: v for f, v in flat.items() if any(f == w or f.startswith(w + ".") for w in fields)}
        for name in flat:
            columns.setdefault(name, None)
        rows.append({"log_time": f"{message.log_time / 1e9:.9f}", "topic": channel.topic, **flat})
    if skipped:
        print(f"cromat bag export: left out (not JSON): {', '.join(sorted(skipped))}", file=sys.stderr)
    if not rows:
        print("cromat bag export: no message matched", file=sys.stderr)
        return 1
    header = ["log_time", "topic", *(sorted(columns) if not fields else
                                     [c for w in fields for c in columns if c == w or c.startswith(w + ".")])]
    with open(args.output, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=header, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {len(rows)} rows x {len(header)} columns to {args.output}", file=out)
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cromat bag", description="Look into MCAP recordings (like ros2 bag).")
    sub = p.add_subparsers(dest="command", required=True)

    def files(sp: argparse.ArgumentParser, many: bool = True) -> None:
        sp.add_argument("files", nargs="+" if many else 1, type=Path, metavar="FILE.mcap")

    def choose(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--select", action="append", metavar="KEYEXPR",
                        help="keys to take (repeatable): a key expression (uav1/dsp/*) or a derived topic "
                             "(/uav1/kinematics)")
        sp.add_argument("--robot", help="only this robot's keys (cromat/ROBOT/..., /ROBOT/...)")
        sp.add_argument("--start", type=float, help="from this time: seconds from the first message, or epoch s")
        sp.add_argument("--end", type=float, help="to this time: seconds from the first message, or epoch s")

    i = sub.add_parser("info", help="channels, types, counts, rates, duration, size, compression")
    files(i)
    i.add_argument("--json", action="store_true", help="one JSON object per file")
    f = sub.add_parser("filter", help="some keys, a robot, a time range into a new MCAP file")
    files(f)
    f.add_argument("-o", "--output", required=True, help="MCAP file to write")
    f.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    choose(f)
    c = sub.add_parser("cat", help="messages as JSON lines")
    files(c)
    c.add_argument("--count", type=int, default=0, help="stop after N messages")
    choose(c)
    e = sub.add_parser("export", help="messages as CSV, one column per field")
    files(e)
    e.add_argument("-o", "--output", required=True, help="CSV file to write")
    e.add_argument("--fields", help="comma-separated fields to keep (a.b keeps a.b and a.b.*); default every one")
    choose(e)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if (missing := require("bag")) is not None:
        print(missing, file=sys.stderr)
        return 2
    for path in args.files:
        if not path.is_file():
            print(f"cromat bag {args.command}: {path}: no such file", file=sys.stderr)
            return 2
    try:
        return {"info": cmd_info, "filter": cmd_filter, "cat": cmd_cat, "export": cmd_export}[args.command](
            args, sys.stdout)
    except BagError as exc:
        print(f"cromat bag {args.command}: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    raise SystemExit(main())
