"""``cromat bus``: see what is on a robot's bus, the way ``ros2 topic`` does.

| command | what |
| --- | --- |
| ``list``   | modules alive, every key with its type, kind, writer, readers and measured rate |
| ``echo``   | decoded data of a slot or key expression (``--json``: one object per line) |
| ``hz``     | rate, interval jitter and bytes/s per key |
| ``schema`` | JSON Schema of a slot (``uav1/dsp/telemetry``) or a struct (``package.module:Class``) |
| ``pub``    | publish a datum given as JSON, validated against the slot's type first |
| ``graph``  | modules, slots and the routes in force (text, or Graphviz DOT with ``--dot``) |

Exit codes: 0 done, 1 refused (``pub`` of an invalid datum) or nothing received, 2 usage, 3 unreachable.
"""

from __future__ import annotations

import argparse
import json
import queue
import sys
import time
from typing import Any, TextIO

import msgspec
import zenoh
import zenoh.ext
from msgspec.json import schema as json_schema

from bbcs import Direction, Kind, Publisher, Safety, SlotSpec
from cromat.tools import keyexpr
from cromat.tools.attendance import Declarations, declarations
from cromat.tools.catalog import Catalog, Decoder, discover, stand_in, struct_type
from cromat.tools.connection import ToolError, add_connection_options, config_from, connect
from cromat.tools.delivery import RouterEcho
from cromat.tools.render import graph_dot, graph_text, yamlish
from cromat.tools.stats import RateMeter


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cromat bus", description="Introspect a robot's bus (like ros2 topic).")
    add_connection_options(p)
    sub = p.add_subparsers(dest="command", required=True)
    ls = sub.add_parser("list", help="modules, keys, types and rates")
    ls.add_argument("--robot", default="*")
    ls.add_argument("--window", type=float, default=2.0, help="seconds to measure rates (0: do not measure)")
    ls.add_argument("--json", action="store_true", help="one JSON object per key")
    e = sub.add_parser("echo", help="print decoded data of a slot or key expression")
    e.add_argument("selection", help="key expression, e.g. uav1/dsp/telemetry, uav1/*/error, uav1/@ral/state")
    e.add_argument("--json", action="store_true", help="one JSON object per line")
    e.add_argument("--count", type=int, default=0, help="stop after N messages (0: until Ctrl-C)")
    e.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: until Ctrl-C)")
    h = sub.add_parser("hz", help="rate, jitter and bytes/s per key")
    h.add_argument("selection")
    h.add_argument("--window", type=float, default=5.0, help="sliding window, seconds")
    h.add_argument("--period", type=float, default=1.0, help="report every S seconds")
    h.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: until Ctrl-C)")
    s = sub.add_parser("schema", help="JSON Schema of a slot or struct")
    s.add_argument("target", help="slot (uav1/dsp/telemetry) or struct type (package.module:Class)")
    pb = sub.add_parser("pub", help="publish a datum given as JSON, validated first")
    # dest slot_key: the connection options' --key (this station's private key) must not be overwritten by it
    pb.add_argument("slot_key", metavar="key", help="slot key, e.g. uav1/ral/pt_datos")
    pb.add_argument("data", help="the datum as a JSON object")
    pb.add_argument("--type", help="struct type package.module:Class (default: the slot's, from the bus)")
    pb.add_argument("--count", type=int, default=1, help="publish N times")
    pb.add_argument("--rate", type=float, default=1.0, help="times per second when --count > 1")
    g = sub.add_parser("graph", help="modules, slots and routes")
    g.add_argument("--robot", default="*")
    g.add_argument("--dot", action="store_true", help="Graphviz DOT instead of text")
    return p


# ---------------------------------------------------------------- receiving

class Feed:
    """Subscribers on key expressions whose samples go to one queue (the callback only enqueues)."""

    def __init__(self, session: zenoh.Session, selections: list[str], *, latched: bool = False) -> None:
        """``latched``: also the last value of every safe state slot, kept by its publisher (as ``record`` gets
        it): a mode or an error published before the tool started is shown at once."""
        self.queue: queue.SimpleQueue[tuple[str, bytes, str, int | None, float]] = queue.SimpleQueue()
        if latched:
            self._subs = [zenoh.ext.declare_advanced_subscriber(
                session, sel, self._on_sample, history=zenoh.ext.HistoryConfig(detect_late_publishers=True))
                for sel in selections]
        else:
            self._subs = [session.declare_subscriber(sel, self._on_sample) for sel in selections]

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        ts = sample.timestamp
        self.queue.put((str(sample.key_expr), sample.payload.to_bytes(), str(sample.encoding),
                        sample_ns(ts), time.time()))

    def get(self, timeout_s: float) -> tuple[str, bytes, str, int | None, float] | None:
        try:
            return self.queue.get(timeout=max(0.0, timeout_s))
        except queue.Empty:
            return None

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        self._subs = []


def sample_ns(ts: zenoh.Timestamp | None) -> int | None:
    """Nanoseconds since the Unix epoch of a sample's Zenoh timestamp (the router stamps every sample)."""
    return None if ts is None else int(ts.get_time_as_ntp64().as_nanos())


class Decoders:
    """One decoder per key, typed from the catalog or the sample's encoding."""

    def __init__(self, catalog: Catalog) -> None:
        self.catalog = catalog
        self._by_key: dict[str, Decoder] = {}

    def type_of(self, key: str, encoding: str = "") -> str:
        return self.catalog.info(key, encoding).type

    def decode(self, key: str, payload: bytes, encoding: str = "") -> tuple[Any, str]:
        dec = self._by_key.get(key)
        if dec is None:
            dec = self._by_key[key] = Decoder(self.type_of(key, encoding))
        return dec.decode(payload)


def _deadline(duration: float) -> float:
    return time.monotonic() + duration if duration > 0 else float("inf")


# ---------------------------------------------------------------- commands

def cmd_list(session: zenoh.Session, args: argparse.Namespace, out: TextIO) -> int:
    cat = discover(session, args.robot, args.timeout, config_from(args))
    declared = declarations(session, min(args.timeout, 2.0))  # before this tool subscribes: not counted
    meters: dict[str, RateMeter] = {}
    encodings: dict[str, str] = {}
    if args.window > 0:
        feed = Feed(session, keyexpr.everything(args.robot))
        end = time.monotonic() + args.window
        try:
            while (left := end - time.monotonic()) > 0:
                got = feed.get(left)
                if got is not None:
                    meters.setdefault(got[0], RateMeter(args.window)).add(time.monotonic(), len(got[1]))
                    encodings.setdefault(got[0], got[2])
        finally:
            feed.close()
        for key in meters:
            cat.info(key, encodings.get(key, ""))
    now = time.monotonic()
    if not cat.modules and not meters:
        print(f"nothing alive on robot {args.robot!r} behind this router", file=sys.stderr)
        return 1
    if args.json:
        for key, s in sorted(cat.slots.items()):
            m = meters.get(key)
            print(json.dumps({"key": key, "type": s.type, "kind": s.kind, "safety": s.safety, "number": s.number,
                              "writers": s.writers, "readers": s.readers,
                              "hz": round(m.rate(now).hz, 3) if m else 0.0, "messages": m.total if m else 0,
                              **dict(zip(("publishers", "subscribers"),
                                         declared.count(key) if declared else (None, None), strict=True))}),
                  file=out)
        return 0
    for robot in cat.robots:
        names = [m.name for (r, _), m in sorted(cat.modules.items()) if r == robot]
        print(f"robot {robot}: {len(names)} modules alive: {', '.join(names)}", file=out)
    out.write("\n".join(list_lines(cat, meters, now, declared)) + "\n")
    if declared is None:
        print("(pub/sub: counts need the router's admin space, [bus] admin_space = true in the manifest)", file=out)
    return 0


LIST_WIDTH = 100
"""``bus list`` rows fit this many columns: the key's line, then its writer and readers indented below."""


def list_lines(cat: Catalog, meters: dict[str, RateMeter], now: float,
               declared: Declarations | None = None) -> list[str]:
    """The table of ``bus list``: per key a line (key, type, kind, rate), and ``writer -> readers`` under it,
    wrapped within :data:`LIST_WIDTH` columns."""
    import textwrap

    width = min(max((len(k) for k in cat.slots), default=3), 44)
    lines = [f"{'key':<{width}} {'type':<22} {'kind':<12} {'rate':>9} {'pub/sub':>7}", f"{'':<4}writer -> readers"]
    for key, s in sorted(cat.slots.items()):
        m = meters.get(key)
        rate = f"{m.rate(now).hz:.1f}Hz" if m and m.total > 1 else ("1 msg" if m else "-")
        kind = f"{s.safety} {s.kind}".strip() or "-"
        counts = "{}/{}".format(*declared.count(key)) if declared else "-"
        head = f"{key:<{width}} {s.short_type:<22.22} {kind:<12} {rate:>9} {counts:>7}"
        lines.append(head[:LIST_WIDTH])
        number = f"#{s.number} " if s.number is not None else ""
        flow = f"{number}{', '.join(s.writers) or '-'} -> {', '.join(s.readers) or '-'}"
        lines += textwrap.wrap(flow, LIST_WIDTH, initial_indent="    ", subsequent_indent="        ",
                               break_on_hyphens=False)
    return lines


def cmd_echo(session: zenoh.Session, args: argparse.Namespace, out: TextIO) -> int:
    selection = keyexpr.expand(args.selection)
    try:
        zenoh.KeyExpr(selection)
    except Exception as exc:
        raise ToolError(f"{args.selection!r} is not a key expression: {exc}") from None
    robot = selection.split("/")[1] if selection.count("/") >= 1 else "*"
    catalog = discover(session, robot if "@" not in robot and "*" not in robot else "*", args.timeout,
                       config_from(args))
    decoders = Decoders(catalog)
    if not catalog.find(selection):
        print(f"cromat bus echo: no module or service on the bus describes a key matching {selection} "
              "(`cromat bus list` shows what is); waiting for data on it anyway", file=sys.stderr, flush=True)
    feed = Feed(session, [selection], latched=True)
    n = 0
    end = _deadline(args.duration)
    try:
        while (not args.count or n < args.count) and time.monotonic() < end:
            got = feed.get(min(0.2, end - time.monotonic()))
            if got is None:
                continue
            key, payload, encoding, ntp, wall = got
            stamp = ntp / 1e9 if ntp is not None else wall
            try:
                value, problem = decoders.decode(key, payload, encoding)
            except ValueError as exc:
                value, problem = None, str(exc)
            typ = decoders.type_of(key, encoding)
            n += 1
            if args.json:
                rec: dict[str, Any] = {"key": key, "type": typ, "stamp": stamp, "data": value}
                if problem:
                    rec["problem"] = problem
                out.write(msgspec.json.encode(rec).decode() + "\n")
            else:
                head = f"--- {key} ({typ or 'unknown type'}) at {time.strftime('%H:%M:%S', time.localtime(stamp))}"
                head += f".{int(stamp % 1 * 1000):03d}"
                out.write("\n".join([head, *(["  ! " + problem] if problem else []), *yamlish(value, 1)]) + "\n")
            out.flush()
    except KeyboardInterrupt:
        pass
    finally:
        feed.close()
    if not n:
        print(f"cromat bus echo: nothing received on {selection}", file=sys.stderr)
    return 0 if n else 1


def cmd_hz(session: zenoh.Session, args: argparse.Namespace, out: TextIO) -> int:
    feed = Feed(session, [keyexpr.expand(args.selection)])
    meters: dict[str, RateMeter] = {}
    end = _deadline(args.duration)
    next_report = time.monotonic() + args.period
    tty = out.isatty()
    shown = 0
    try:
        while time.monotonic() < end:
            got = feed.get(min(next_report, end) - time.monotonic())
            now = time.monotonic()
            if got is not None:
                meters.setdefault(got[0], RateMeter(args.window)).add(now, len(got[1]))
            if now >= next_report:
                next_report += args.period
                lines = hz_lines(meters, now)
                if tty and shown:
                    out.write(f"\x1b[{shown}F\x1b[J")
                out.write("\n".join(lines) + "\n")
                out.flush()
                shown = len(lines)
    except KeyboardInterrupt:
        pass
    finally:
        feed.close()
    return 0 if meters else 1


def hz_lines(meters: dict[str, RateMeter], now: float) -> list[str]:
    lines = [f"{'key':<40} {'rate':>9} {'jitter':>9} {'min':>8} {'max':>8} {'bytes/s':>9} {'total':>7}"]
    for key, m in sorted(meters.items()):
        r = m.rate(now)
        lines.append(f"{key:<40} {r.hz:7.2f}Hz {r.jitter_s * 1000:7.2f}ms {r.min_interval_s * 1000:6.1f}ms "
                     f"{r.max_interval_s * 1000:6.1f}ms {r.bytes_per_s:9.0f} {m.total:>7}")
    return lines


def cmd_schema(session_factory: Any, args: argparse.Namespace, out: TextIO) -> int:
    if ":" in args.target:
        typ = struct_type(args.target)
        if typ is None:
            raise ToolError(f"no struct type {args.target!r} in this installation (package.module:Class)")
        print(json.dumps(json_schema(typ), indent=2), file=out)
        return 0
    key = keyexpr.expand(args.target)
    session = session_factory()
    try:
        cat = discover(session, key.split("/")[1], args.timeout, config_from(args))
        info = cat.slots.get(key) or cat.info(key)
        if not info.schema:  # no description: a sample's encoding names its struct (@ral/fleet, a replayed key)
            feed = Feed(session, [key], latched=True)
            try:
                got = feed.get(args.timeout)
            finally:
                feed.close()
            if got is not None:
                info = cat.info(key, got[2])
    finally:
        session.close()
    if not info.schema:
        if info.type:
            raise ToolError(f"{key} carries {info.type}, which is not installed here: no schema to show", 1)
        raise ToolError(f"no module on the bus describes {key} and nothing arrived on it within {args.timeout:g} s "
                        "(is it alive? `cromat bus list` shows what is)", 1)
    print(json.dumps({"key": key, "type": info.type, **info.schema}, indent=2), file=out)
    return 0


def validate_datum(text: str, typ: type[msgspec.Struct] | None, schema: dict[str, Any]) -> tuple[Any, str]:
    """``(value, reason)``: the datum as the slot's struct (or validated dict), or why it is refused."""
    try:
        raw = json.loads(text)
    except ValueError as exc:
        return None, f"not JSON: {exc}"
    if not isinstance(raw, dict):
        return None, "the datum must be a JSON object of the slot's fields"
    if typ is not None:
        unknown = sorted(set(raw) - set(typ.__struct_fields__))
        if unknown:
            return None, (f"field $.{unknown[0]}: {typ.__name__} has no such field "
                          f"(fields: {', '.join(typ.__struct_fields__)})")
        try:
            return msgspec.convert(raw, typ), ""
        except msgspec.ValidationError as exc:
            return None, _field_first(str(exc))
    try:
        import jsonschema
    except ImportError:
        return None, "the slot's struct is not installed here and jsonschema is missing to check its schema"
    errors = sorted(jsonschema.Draft202012Validator(schema).iter_errors(raw), key=lambda e: list(e.path))
    if errors:
        err = errors[0]
        path = "$" + "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in err.path)
        return None, f"field {path}: {err.message}"
    return raw, ""


def _field_first(message: str) -> str:
    """msgspec's ``Expected ... - at `$.x``` as ``field $.x: Expected ...``."""
    text, sep, path = message.rpartition(" - at `")
    return f"field {path.rstrip('`')}: {text}" if sep else message


def cmd_pub(session: zenoh.Session, args: argparse.Namespace, out: TextIO) -> int:
    key = keyexpr.expand(args.slot_key)
    parts = key.split("/")
    if len(parts) != 4 or any(c in key for c in "*$?#"):
        raise ToolError(f"{args.slot_key!r} is not one slot key (robot/module/slot)")
    cat = discover(session, parts[1], args.timeout, config_from(args))
    info = cat.info(key)
    type_name_ = args.type or info.type
    typ = struct_type(type_name_) if type_name_ else None
    if typ is None and not info.schema:
        raise ToolError(f"the type of {key} is unknown (no module describes it): give --type package.module:Class")
    value, reason = validate_datum(args.data, typ, info.schema)
    if reason:
        print(f"cromat bus pub: refused, nothing sent: {reason}", file=sys.stderr)
        return 1
    spec_type = typ or stand_in(type_name_)
    spec = SlotSpec(parts[3], spec_type, Direction.OUT, Kind(info.kind or "state"),
                    Safety(info.safety or "safe") if (info.kind or "state") == "state" else Safety.SAFE)
    echo = RouterEcho(args, [key])
    pub = Publisher(session, key, spec)
    sent = max(1, args.count)
    try:
        _wait_matching(session, key, args.timeout)  # the echo's subscription known here: the first put is not lost
        payload = msgspec.msgpack.encode(value)
        for i in range(sent):
            if i:
                time.sleep(1.0 / args.rate)
            pub.publish_raw(payload)
        delivered = echo.wait({key: sent}, args.timeout)[key]
    finally:
        pub.close()
        echo.close()
    if not delivered:
        print(f"cromat bus pub: the router delivered none of the {sent} put on {key}: its access policy drops "
              f"this identity's writes there (or the router is gone)", file=sys.stderr)
        return 1
    print(f"published {sent} x {type_name_ or 'datum'} on {key} (the router delivered {delivered})", file=out)
    return 0 if delivered >= sent else 1


def _wait_matching(session: zenoh.Session, key: str, timeout_s: float) -> None:
    probe = session.declare_publisher(key)
    try:
        deadline = time.monotonic() + timeout_s
        while not probe.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        probe.undeclare()


def cmd_graph(session: zenoh.Session, args: argparse.Namespace, out: TextIO) -> int:
    cat = discover(session, args.robot, args.timeout, config_from(args))
    if not cat.modules:
        print(f"nothing alive on robot {args.robot!r} behind this router", file=sys.stderr)
        return 1
    print(graph_dot(cat) if args.dot else "\n".join(graph_text(cat)), file=out)
    return 0


def run(args: argparse.Namespace, out: TextIO) -> int:
    if args.command == "schema":
        return cmd_schema(lambda: connect(args), args, out)
    session = connect(args)
    try:
        handler = {"list": cmd_list, "echo": cmd_echo, "hz": cmd_hz, "pub": cmd_pub, "graph": cmd_graph}
        return handler[args.command](session, args, out)
    finally:
        session.close()


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return run(args, sys.stdout)
    except ToolError as exc:
        print(f"cromat bus: {exc}", file=sys.stderr)
        return exc.code
    except BrokenPipeError:
        return 0


