"""The router's refusals in its own log: denied messages and refused links, counted and rate limited.

Zenoh decides access control and TLS in Rust and reports only through its tracing log: a denied message is a
TRACE line of ``zenoh::net::routing::interceptor::access_control`` ("<zid> on …CertCommonName(<cn>)… is
unauthorized to Put (ingress) on <key>"), a refused TLS link a WARN line of ``zenoh_link_tls`` ("peer sent no
certificates", "invalid peer certificate: …"). That log goes to the process's stdout. With ``cromat router
--log-refusals`` the router reads its own stdout through a pipe, turns those lines into one readable line per
refusal, counts them by kind, and prints at most ``burst`` of them per ``period_s`` (then one line saying how
many were left out), passing every other line through unchanged.

Not every "unauthorized" line is a refusal. When a client declares a key expression (a publisher, subscriber,
token or queryable), the ACL fills a permission table for it: a line "caching permissions for `<key>` ..." and
then one line per message kind (9 of them), denied kinds included, although nothing was refused. A denial of a
real message is a line of its own, or "Using cached result: <zid> is unauthorized to …" (zid only: the CN is
learnt from the identity's earlier lines). :class:`LogReader` skips the tables and names identities by CN.

Cost: Zenoh has no level for denials alone; at TRACE the ACL target writes a line for every message it checks,
allowed ones included, which this reader parses and drops. So the option is off by default; it is meant for
commissioning and for investigating a refusal.
"""

from __future__ import annotations

import atexit
import os
import re
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import BinaryIO, TextIO

LOG_FILTER = "warn,zenoh::net::routing::interceptor::access_control=trace"
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_DENIED = re.compile(r"CertCommonName\((?P<cn>[^)]*)\).* is unauthorized to (?P<what>.+?) \((?P<flow>\w+)\) on "
                     r"(?P<key>\S+)")
_DENIED_NO_CN = re.compile(r"access_control: (?P<zid>\w+) .* is unauthorized to (?P<what>.+?) \((?P<flow>\w+)\) on "
                           r"(?P<key>\S+)")
_TABLE = re.compile(r"ThreadId\((?P<thread>\d+)\).*caching permissions for `(?P<key>[^`]*)`")
_THREAD = re.compile(r"ThreadId\((?P<thread>\d+)\)")
_ZID_CN = re.compile(r"access_control: (?:Using cached result: )?(?P<zid>[0-9a-f]+) on "
                     r"\S*CertCommonName\((?P<cn>[^)]*)\)")
_CACHED = re.compile(r"Using cached result: (?P<zid>[0-9a-f]+) is unauthorized to (?P<what>.+?) \((?P<flow>\w+)\) "
                     r"on (?P<key>\S+)")
_ALLOWED = b" is authorized to "
_CACHED_HIT = b"Using cached result"
TABLE_LINES = 9
"""Message kinds in one permission table (Zenoh 1.x ACL: query, reply, put, delete, 3 declarations, 2 liveliness)."""
_MESH_REFUSED = re.compile(r"close message \(reason (?P<why>INVALID|CONNECTION_TO_SELF)\) in response to an OpenSyn "
                           r"on: .*? dst: (?P<dst>[^,\s]+)")
_SELF_LINK = re.compile(r"zenoh_transport::unicast::manager\S*: (?P<zid>[0-9a-f]+) Attempt to establish transport to "
                        r"itself")
LINK_LOG_FILTER = "warn"
"""Enough for refused links (a TLS refusal is a WARN line, a mesh's refusal an ERROR line), with no ACL tracing."""
MESH_REFUSED = "mesh refused"
_LINK = re.compile(r"zenoh_link_tls\S*: (?P<why>[^.]*(?:certificate|handshake failed|alert)[^.]*)", re.IGNORECASE)


@dataclass(frozen=True)
class Refusal:
    kind: str  # "denied" or "link refused"
    text: str


def parse(line: str) -> Refusal | None:
    """The refusal a Zenoh log line reports, or None for any other line."""
    line = _ANSI.sub("", line)
    m = _DENIED.search(line) or _DENIED_NO_CN.search(line)
    if m:
        who = m.groupdict().get("cn") or m.groupdict().get("zid")
        return Refusal("denied", f"{who} may not {m['what'].lower()} on {m['key']} ({m['flow']})")
    m = _MESH_REFUSED.search(line)
    if m:
        return Refusal(MESH_REFUSED, f"the router at {m['dst']} closed this router's link at the handshake (reason "
                       f"{m['why']}): a router with this router's Zenoh id is already on that mesh. A robot's router "
                       "takes its id from the robot name, so another robot of this name is most likely there: "
                       "robot names must be unique (rename one in [robot] name)")
    m = _SELF_LINK.search(line)
    if m:
        return Refusal(MESH_REFUSED, f"refused a link from a router with this router's own Zenoh id ({m['zid']}): "
                       "another robot of this name tried to join the mesh here; robot names must be unique "
                       "(rename one in [robot] name)")
    m = _LINK.search(line)
    if m and "eof" not in m["why"]:
        return Refusal("link refused", m["why"].strip())
    return None


class LogReader:
    """Turns Zenoh log lines into refusals, line by line, skipping the ACL's permission tables (see above)."""

    def __init__(self) -> None:
        self.names: dict[str, str] = {}
        self._table: dict[str, tuple[str, int]] = {}  # thread → (key, permission lines still to skip)

    def feed(self, line: str) -> Refusal | None:
        line = _ANSI.sub("", line)
        if "access_control" in line:
            if m := _ZID_CN.search(line):
                self.names[m["zid"]] = m["cn"]
            if m := _TABLE.search(line):
                self._table[m["thread"]] = (m["key"], TABLE_LINES)
                return None
            thread = m["thread"] if (m := _THREAD.search(line)) else ""
            key, left = self._table.get(thread, ("", 0))
            if left and "Using cached result" not in line and "authorized to" in line and line.endswith(f" on {key}"):
                self._table[thread] = (key, left - 1)
                return None
            if m := _CACHED.search(line):
                who = self.names.get(m["zid"], m["zid"])
                return Refusal("denied", f"{who} may not {m['what'].lower()} on {m['key']} ({m['flow']})")
        return parse(line)


class RefusalLog:
    """Counts refusals by kind and lets through at most ``burst`` lines of each kind per ``period_s`` (injected
    clock), so a flood of denied messages never hides a refused link."""

    def __init__(self, clock: Callable[[], float] = time.monotonic, period_s: float = 10.0, burst: int = 5) -> None:
        self.clock = clock
        self.period_s = period_s
        self.burst = burst
        self.counts: Counter[str] = Counter()
        self._window_start: dict[str, float] = {}
        self._shown: Counter[str] = Counter()
        self._hidden: Counter[str] = Counter()

    def note(self, refusal: Refusal) -> list[str]:
        """Lines to print for this refusal (none when rate limited; a summary when its window closes)."""
        kind = refusal.kind
        self.counts[kind] += 1
        out: list[str] = []
        now = self.clock()
        if now - self._window_start.setdefault(kind, now) >= self.period_s:
            if self._hidden[kind]:
                out.append(f"cromat router: {self._hidden[kind]} more {kind} not shown in the last {self.period_s:g} s")
            self._window_start[kind], self._shown[kind], self._hidden[kind] = now, 0, 0
        if self._shown[kind] < self.burst:
            self._shown[kind] += 1
            out.append(f"cromat router: {kind}: {refusal.text} ({self.counts[kind]} {kind} so far)")
        else:
            self._hidden[kind] += 1
        return out


def install(out: TextIO, log: RefusalLog | None = None, log_filter: str | None = None,
            consume: Callable[[bytes], bytes] | None = None) -> RefusalLog:
    """Route this process's stdout (where Zenoh logs) through a reader that reports refusals on ``out``.

    Call before the Zenoh session is opened; ``out`` must be a stream on a *duplicate* of the real stdout.
    ``log_filter``: Zenoh's log filter (default ``LOG_FILTER``, with the ACL's denials; ``LINK_LOG_FILTER``:
    refused links only). ``consume``: takes whole lines in chunks first and returns what the rest should see
    (bbcs/router_floods.py).
    """
    import zenoh

    log = log or RefusalLog()
    reader = LogReader()
    read_fd, write_fd = os.pipe()
    os.dup2(write_fd, 1)
    os.close(write_fd)

    def lines_of(pipe: BinaryIO) -> Iterator[bytes]:
        if consume is None:
            yield from pipe
            return
        tail = b""
        while chunk := pipe.read1(1 << 20):  # whole chunks: ``consume`` takes its lines out at C speed
            data = tail + chunk
            cut = data.rfind(b"\n") + 1
            data, tail = consume(data[:cut]), data[cut:]
            yield from data.splitlines(keepends=True)

    def pump() -> None:
        with os.fdopen(read_fd, "rb", buffering=1 << 16) as pipe:
            for raw in lines_of(pipe):
                if _ALLOWED in raw and _CACHED_HIT in raw:  # the bulk: an allowed message, nothing to parse
                    continue
                line = raw.decode(errors="replace")
                refusal = reader.feed(line.rstrip("\n"))
                lines = log.note(refusal) if refusal is not None else ([] if _is_zenoh_log(line) else [line.rstrip()])
                if lines:
                    out.write("".join(text + "\n" for text in lines))
                    out.flush()

    threading.Thread(target=pump, name="router-refusals", daemon=True).start()
    # at exit the reader thread dies first; Zenoh's last trace lines would then fill the pipe and block the exit
    atexit.register(_detach_stdout)
    zenoh.init_log_from_env_or(log_filter or LOG_FILTER)
    return log


def _detach_stdout() -> None:
    """Point fd 1 at /dev/null: nothing may still write into a pipe nobody reads."""
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    os.close(null)


def _is_zenoh_log(line: str) -> bool:
    """A Zenoh tracing line that is not a refusal (allowed-message traces, warnings): kept out of the log."""
    return bool(re.match(r"^\S*\d{4}-\d\d-\d\dT\S+Z", _ANSI.sub("", line)))
