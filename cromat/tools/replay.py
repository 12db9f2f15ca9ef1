"""``cromat replay FILE...``: republish a recording onto a router, in recorded order.

At 1x (default), N x (``--speed N``) or as fast as possible (``--fast``); ``--robot-map OLD=NEW`` moves
``cromat/OLD/...`` to ``cromat/NEW/...`` and renames the robot inside data that carry a ``robot`` field (GRI
state and events), so a ground station watching NEW sees the flight. Each JSON message is turned back into the
msgpack bytes that were on the bus through the struct named in its channel. Every key is published reliably
(an unsafe slot's best-effort delivery would drop messages of a fast replay); state keys keep their last value
for late joiners.

A replayed robot is live to every tool (:class:`LiveRobot`): its modules' liveliness tokens, their ``@schema``
answers and the manager's ``routes`` answer as recorded, and every epoch ``stamp`` in the data moved to now
(``--keep-stamps`` keeps them as recorded).
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import msgspec
import zenoh

from bbcs import Direction, Kind, Publisher, Safety, SlotSpec, forward_stop_signals
from cromat.tools import keyexpr, mcapfmt
from cromat.tools.catalog import stand_in, struct_type
from cromat.tools.connection import ToolError, add_connection_options, connect
from cromat.tools.delivery import RouterEcho, dropped_keys
from cromat.tools.extras import require
from cromat.tools.progress import StatusLine, bar


@dataclass
class Encoder:
    """JSON message → bus bytes for one channel."""

    key: str
    type: type[msgspec.Struct] | None
    remap: tuple[str, str] | None
    shift_s: float = 0.0
    """Added to every epoch stamp in the data (:func:`rebase_stamps`)."""

    def __call__(self, data: bytes) -> bytes:
        if self.shift_s:
            data = msgspec.json.encode(rebase_stamps(msgspec.json.decode(data), self.shift_s))
        if self.type is None:
            return msgspec.msgpack.encode(msgspec.json.decode(data))
        value = msgspec.json.decode(data, type=self.type)
        if self.remap and getattr(value, "robot", None) == self.remap[0]:
            value = msgspec.structs.replace(value, robot=self.remap[1])
        return msgspec.msgpack.encode(value)


EPOCH_AFTER = 1e9
"""A ``stamp`` above this many seconds is a time since the epoch (after 2001); smaller ones (monotonic clocks,
frame stamps) are not moved."""


def rebase_stamps(value: Any, shift_s: float) -> Any:
    """``value`` (decoded JSON) with every field named ``stamp`` or ``*_stamp`` that holds an epoch time moved by
    ``shift_s`` seconds, at any depth: a replayed flight's states, telemetry, errors and events then read as now."""
    if isinstance(value, dict):
        return {k: (v + shift_s if (k == "stamp" or k.endswith("_stamp")) and isinstance(v, float | int)
                    and not isinstance(v, bool) and v > EPOCH_AFTER else rebase_stamps(v, shift_s))
                for k, v in value.items()}
    if isinstance(value, list):
        return [rebase_stamps(v, shift_s) for v in value]
    return value


class LiveRobot:
    """What makes a replayed robot look alive to every tool, from the recording's ``cromat.bus`` metadata and
    its channels: a liveliness token per module (``cromat gcs robots``, ``cromat bus list``), the modules' and
    services' ``@schema`` answers, and the manager's ``routes`` answer (``cromat bus graph``), robot renamed."""

    def __init__(self, session: zenoh.Session, remap: tuple[str, str] | None) -> None:
        self.session = session
        self.remap = remap
        self._entities: list[Any] = []
        self.modules: set[tuple[str, str]] = set()

    def _key(self, key: str) -> str:
        return keyexpr.remap_robot(key, *self.remap) if self.remap else key

    def _text(self, text: str) -> str:
        if not self.remap:
            return text
        return text.replace(f'"cromat/{self.remap[0]}/', f'"cromat/{self.remap[1]}/')

    def start(self, bus_meta: dict[str, str], channel_keys: list[str]) -> None:
        from bbcs import keys
        from bbcs.contracts import mri

        schemas = json.loads(bus_meta.get("schemas") or "{}")
        routes = json.loads(bus_meta.get("routes") or "{}")
        for key in [*schemas, *channel_keys]:
            parts = self._key(key).split("/")
            if len(parts) == 4 and parts[3] in ("@schema", "@heartbeat", "@route") and not parts[2].startswith("@"):
                self.modules.add((parts[1], parts[2]))
            elif len(parts) >= 3 and parts[2] == "@ral":
                self.modules.add((parts[1], "ral"))
        for key, doc in schemas.items():  # each answers on its own key, as the modules do (a wildcard query)
            payload, own = self._text(json.dumps(doc)).encode(), self._key(key)
            self._entities.append(self.session.declare_queryable(
                own, lambda q, own=own, payload=payload: q.reply(own, payload)))
        for robot, table in routes.items():
            reply = mri.encode(mri.MriReply(ok=True, data=msgspec.convert(table, mri.RouteList, str_keys=True)))
            robot = self.remap[1] if self.remap and robot == self.remap[0] else robot
            own = mri.mri_key(robot, "routes")
            self._entities.append(self.session.declare_queryable(
                own, lambda q, own=own, reply=reply: q.reply(own, reply)))
        # the tokens last: a tool that sees the robot alive finds its descriptions already answered
        for robot, module in sorted(self.modules):
            self._entities.append(self.session.liveliness().declare_token(keys.alive_key(robot, module)))

    def close(self) -> None:
        for entity in self._entities:
            entity.undeclare()
        self._entities = []


def _reader(stream: Any) -> Any:
    from mcap.reader import make_reader  # the tools extra (main() checks it is installed)

    return make_reader(stream)


def messages(files: list[Path]) -> Iterator[tuple[Any, Any]]:
    """``(channel, message)`` of every file, in the order they were written."""
    for path in files:
        with open(path, "rb") as f:
            for _schema, channel, message in _reader(f).iter_messages(log_time_order=False):
                yield channel, message


def recording_meta(path: Path, name: str) -> dict[str, str]:
    """The metadata record ``name`` of a file ({} when it has none)."""
    with open(path, "rb") as f:
        for record in _reader(f).iter_metadata():
            if record.name == name:
                return dict(record.metadata)
    return {}


def time_range(files: list[Path]) -> tuple[int, int, int]:
    """First and last log time (ns) and message count, from the files' statistics. The first is when the
    recording began when the file says so: the RAL's cached GRI events are logged at their own, earlier stamps,
    and are published at once, not waited for."""
    start, end, count = None, None, 0
    began = [int(v) for p in files[:1] if (v := recording_meta(p, "cromat.recording").get("started_ns"))]
    for path in files:
        with open(path, "rb") as f:
            summary = _reader(f).get_summary()
        st = summary.statistics if summary is not None else None
        if st is None or not st.message_count:
            continue
        start = st.message_start_time if start is None else min(start, st.message_start_time)
        end = st.message_end_time if end is None else max(end, st.message_end_time)
        count += st.message_count
    if began and start is not None and start < began[0] <= (end or 0):
        start = began[0]
    return start or 0, end or 0, count


class Replayer:
    def __init__(self, session: zenoh.Session, remap: tuple[str, str] | None = None, shift_s: float = 0.0) -> None:
        self.session = session
        self.remap = remap
        self.shift_s = shift_s
        self._pubs: dict[str, tuple[Publisher[Any], Encoder]] = {}
        """recorded key → its publisher (channel ids differ between the files of a split recording)"""
        self.published: dict[str, int] = {}
        self.failed = 0

    def declare(self, channel: Any) -> tuple[Publisher[Any], Encoder]:
        meta = channel.metadata or {}
        key = meta.get(mcapfmt.META_KEY, channel.topic)
        if key in self._pubs:
            return self._pubs[key]
        tname = meta.get(mcapfmt.META_TYPE, "")
        typ = struct_type(tname)
        out_key = keyexpr.remap_robot(key, *self.remap) if self.remap else key
        kind = Kind(meta.get(mcapfmt.META_KIND) or "state")
        safety = Safety.SAFE  # every recorded message is delivered: unsafe slots are replayed reliably too
        name = out_key.rsplit("/", 1)[-1].lstrip("@") or "slot"
        spec = SlotSpec(name, typ or stand_in(tname), Direction.OUT, kind, safety)
        pair = (Publisher(self.session, out_key, spec), Encoder(out_key, typ, self.remap, self.shift_s))
        self._pubs[key] = pair
        return pair

    def publish(self, key: str, channel: Any, data: bytes) -> None:
        pub, enc = self._pubs.get(key) or self.declare(channel)
        try:
            payload = enc(data)
        except (msgspec.DecodeError, msgspec.ValidationError):
            self.failed += 1
            return
        pub.publish_raw(payload)
        self.published[pub.key] = self.published.get(pub.key, 0) + 1

    def rebase(self, shift_s: float) -> None:
        """Move every stamp by ``shift_s`` seconds from now on."""
        self.shift_s = shift_s
        for _, enc in self._pubs.values():
            enc.shift_s = shift_s

    @property
    def keys(self) -> list[str]:
        """The keys this replay publishes on (after ``--robot-map``)."""
        return [pub.key for pub, _ in self._pubs.values()]

    def wait_for_subscribers(self, timeout: float, stop: threading.Event) -> list[str]:
        """Wait until the router has told this session of a subscriber for every key to be replayed, at most
        ``timeout`` s (or until ``stop``); returns the keys still without one. Without this wait the first
        messages of a fast replay went to a router that did not yet route them to anyone. One plain publisher per
        key, which never puts, tells its matching status (a state key's publisher, which keeps the last value for
        late joiners, has none)."""
        pending = set(self.keys)
        lock = threading.Lock()
        changed = threading.Event()

        def matched(key: str, status: Any) -> None:
            if status.matching:
                with lock:
                    pending.discard(key)
                changed.set()

        probes, listeners = [], []
        try:
            for key in sorted(pending):
                probe = self.session.declare_publisher(key)
                probes.append(probe)
                listeners.append(probe.declare_matching_listener(lambda st, key=key: matched(key, st)))
                if probe.matching_status.matching:
                    with lock:
                        pending.discard(key)
            deadline = time.monotonic() + timeout
            while not stop.is_set():
                with lock:
                    if not pending:
                        break
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                changed.wait(left)
                changed.clear()
        finally:
            for listener in listeners:
                listener.undeclare()
            for probe in probes:
                probe.undeclare()
        with lock:
            return sorted(pending)

    def close(self) -> None:
        for pub, _ in self._pubs.values():
            pub.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cromat replay", description="Republish an MCAP recording onto a router.")
    add_connection_options(p)
    p.add_argument("files", nargs="+", help="MCAP file(s) from cromat record, in order (split recordings)")
    speed = p.add_mutually_exclusive_group()
    speed.add_argument("--speed", type=float, default=1.0, help="playback speed factor (default 1x)")
    speed.add_argument("--fast", action="store_true", help="as fast as possible")
    p.add_argument("--robot-map", metavar="OLD=NEW", help="publish robot OLD's data as robot NEW")
    p.add_argument("--select", action="append", metavar="KEYEXPR", help="only keys matching (repeatable)")
    p.add_argument("--keep-stamps", action="store_true",
                   help="publish the data's stamps as recorded (default: moved so the recording begins now)")
    p.add_argument("--settle", type=float, default=1.0,
                   help="at most this many seconds to wait, before the first message, for the router to know a "
                        "subscriber of every key (default 1; it starts at once when all have one)")
    return p


def run(args: argparse.Namespace, out: TextIO) -> int:
    files = [Path(f) for f in args.files]
    for f in files:
        if not f.is_file():
            raise ToolError(f"{f}: no such file")
    remap = None
    if args.robot_map:
        old, sep, new = args.robot_map.partition("=")
        if not sep or not old or not new:
            raise ToolError("--robot-map takes OLD=NEW")
        remap = (old, new)
    if args.speed <= 0:
        raise ToolError("--speed must be > 0 (use --fast for as fast as possible)")
    selections = [keyexpr.expand(s) for s in args.select or []]
    try:
        first, last, total = time_range(files)
    except Exception as exc:
        raise ToolError(f"not a readable MCAP recording: {exc}") from None
    session = connect(args)
    stop = threading.Event()
    restore_signals = forward_stop_signals(lambda _signum: stop.set())  # never a lock in a signal handler
    shift_s = 0.0 if args.keep_stamps or not first else time.time() - first / 1e9
    rep = Replayer(session, remap, shift_s)
    live = LiveRobot(session, remap)
    unheard: list[str] = []
    echo: RouterEcho | None = None
    status = StatusLine()
    n = 0
    try:
        # declare every publisher first, then wait (at most --settle) until every key has a subscriber
        for path in files:
            with open(path, "rb") as f:
                summary = _reader(f).get_summary()
            for ch in (summary.channels.values() if summary else []):
                key = (ch.metadata or {}).get(mcapfmt.META_KEY, ch.topic)
                if not selections or any(keyexpr.intersects(s, key) for s in selections):
                    rep.declare(ch)
        live.start(recording_meta(files[0], mcapfmt.META_BUS), list(rep._pubs))
        unheard = rep.wait_for_subscribers(args.settle, stop)
        echo = RouterEcho(args, rep.keys)  # after that wait: the echo is no consumer of the robot's
        rep.wait_for_subscribers(args.timeout, stop)  # the echo's subscriptions known here: nothing missed
        if shift_s:  # the recording's start is now, after the wait
            rep.rebase(time.time() - first / 1e9)
        wall0 = time.monotonic()
        for channel, message in messages(files):
            if stop.is_set():
                break
            key = (channel.metadata or {}).get(mcapfmt.META_KEY, channel.topic)
            if selections and not any(keyexpr.intersects(s, key) for s in selections):
                continue
            if not args.fast:
                due = wall0 + (message.log_time - first) / 1e9 / args.speed
                delay = due - time.monotonic()
                if delay > 0 and stop.wait(delay):
                    break
            rep.publish(key, channel, message.data)
            n += 1
            if last > first:
                frac = (message.log_time - first) / (last - first)
                status.show(f"replay {bar(frac)} {frac * 100:5.1f}%  {n}/{total} msgs  "
                            f"t={(message.log_time - first) / 1e9:7.1f} s")
        status.done()
        delivered = echo.wait(dict(rep.published), args.timeout) if echo is not None else {}
    finally:
        restore_signals()
        live.close()
        rep.close()
        if echo is not None:
            echo.close()
        session.close()
    print(f"replayed {sum(rep.published.values())} of {total} messages on {len(rep.published)} keys"
          + (f" ({rep.failed} could not be re-encoded)" if rep.failed else "")
          + (" (interrupted)" if stop.is_set() else ""), file=out)
    if unheard:
        print(f"{len(unheard)} of {len(rep.keys)} keys had no subscriber when the replay began "
              f"(--settle {args.settle:g} s): {', '.join(unheard[:5])}{' ...' if len(unheard) > 5 else ''}", file=out)
    sent = sum(rep.published.values())
    print(f"the router delivered {sum(delivered.values())} of {sent}", file=out)
    dropped = dropped_keys(dict(rep.published), delivered)
    if dropped:
        print(f"cromat replay: the router delivered nothing on {len(dropped)} of {len(rep.published)} keys (its "
              f"access policy drops this identity's writes there): {', '.join(dropped[:5])}"
              f"{' ...' if len(dropped) > 5 else ''}", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if (missing := require("replay")) is not None:
        print(missing, file=sys.stderr)
        return 2
    try:
        return run(args, sys.stdout)
    except ToolError as exc:
        print(f"cromat replay: {exc}", file=sys.stderr)
        return exc.code


if __name__ == "__main__":
    raise SystemExit(main())
