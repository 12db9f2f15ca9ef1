"""``cromat gcs``: the ground-station command line, a thin shell over :mod:`ral.gcs.api`.

Exit codes: 0 done, 1 the robot rejected or refused the request, 2 usage or file error, 3 unreachable, refused
credentials, no answer, or no such robot.

``--connect``, ``--ca``, ``--cert``, ``--key``, ``--config`` and ``--name`` default to the environment variables
``CROMAT_GCS_CONNECT`` (comma-separated endpoints), ``CROMAT_GCS_CA``, ``CROMAT_GCS_CERT``, ``CROMAT_GCS_KEY``,
``CROMAT_GCS_CONFIG`` and ``CROMAT_GCS_NAME``.
"""

from __future__ import annotations

import argparse
import faulthandler
import math
import os
import sys
import threading
import time
from typing import TextIO

import msgspec

from bbcs.contracts import gri
from bbcs.contracts.error_codes import error_name
from ral import fleet_gcs
from ral.gcs import fleet_cmd, task_args, watch_view
from ral.gcs.api import Gcs, GcsError, NoReply, Unreachable, UsageError, session_config
from ral.gcs.waypoints import WaypointFileError


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cromat gcs", description="Ground control station for cromat robots.")
    env = os.environ
    p.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        default=[e for e in env.get("CROMAT_GCS_CONNECT", "").split(",") if e.strip()] or None,
        help="robot router endpoint, e.g. tls/robot1:7447 (repeatable; env CROMAT_GCS_CONNECT, comma-separated; "
        "default tcp/127.0.0.1:7447)",
    )
    p.add_argument("--ca", default=env.get("CROMAT_GCS_CA"),
                   help="CA certificate (PEM) that signed the router's certificate (tls/; env CROMAT_GCS_CA)")
    p.add_argument("--cert", default=env.get("CROMAT_GCS_CERT"),
                   help="this station's certificate (PEM) for mutual TLS (env CROMAT_GCS_CERT)")
    p.add_argument("--key", default=env.get("CROMAT_GCS_KEY"),
                   help="this station's private key (PEM) (env CROMAT_GCS_KEY)")
    p.add_argument("--config", metavar="FILE", default=env.get("CROMAT_GCS_CONFIG"),
                   help="Zenoh JSON5 config file, applied first (env CROMAT_GCS_CONFIG)")
    p.add_argument("--name", default=env.get("CROMAT_GCS_NAME", "gcs"),
                   help="station name (liveliness token), default gcs (env CROMAT_GCS_NAME)")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for answers (default 5)")
    sub = p.add_subparsers(dest="command", required=True)
    sub.add_parser("robots", help="list live robots")
    w = sub.add_parser("watch", help="live robot state, refreshed in place; a passive observer: no GCS link")
    w.add_argument("robot", help="robot name, or '*' for every robot behind the router")
    w.add_argument("--count", type=int, default=0, help="stop after this many states (0: until Ctrl-C)")
    w.add_argument("--events", action="store_true", help="piped: also print events (a terminal shows the last ones)")
    w.add_argument("--link", action="store_true",
                   help="also hold a GCS link with ROBOT (its link-loss failsafe then counts this station, and runs "
                        "when it goes away)")
    lk = sub.add_parser("link", help="hold a GCS link with these robots until Ctrl-C: their link-loss failsafe "
                                     "counts this station (and runs once it is gone for failsafe_timeout_s)")
    lk.add_argument("robots", nargs="+", metavar="ROBOT")
    lk.add_argument("--seconds", type=float, default=0.0, help="let go after this long (0: until Ctrl-C)")
    t = sub.add_parser("task", help="submit a task")
    t.add_argument("robot")
    task_args.add_parsers(t)  # one subcommand per task kind, from its struct (ral/gcs/task_args.py)
    a = sub.add_parser("abort", help="stop every task of a robot now")
    a.add_argument("robot")
    m = sub.add_parser("modules", help="module health, restarts and routes")
    m.add_argument("robot")
    r = sub.add_parser("route", help="swap a module's input to another slot number (-1: ignore)")
    r.add_argument("robot")
    r.add_argument("module")
    r.add_argument("input")
    r.add_argument("slot", type=int)
    e = sub.add_parser("errors", help="a robot's most recent errors: module, code, name, detail")
    e.add_argument("robot")
    fleet_gcs.add_parser(sub)
    rs = sub.add_parser("restart", help="restart one module (its running tasks fail)")
    rs.add_argument("robot")
    rs.add_argument("module")
    fleet_cmd.add_parsers(sub)  # world / sync (issue 17)
    return p


task_request = task_args.task_request


def format_state(s: gri.GriState) -> str:
    tel = s.telemetry
    p = tel.position if tel else None
    pos = f"{p.lat:.6f} {p.lon:.6f} {p.alt:.1f} m above sea level" if p else "unknown"
    tasks = ", ".join(f"{t.task_type}:{t.kind or t.name}#{t.id}({t.origin})" for t in s.tasks) or "none"
    mods = " ".join(f"{m.name}={m.state}" for m in s.modules) or "-"
    mode = (tel.mode_name or tel.mode) if tel else None
    return (
        f"{s.robot} [{s.kind or '?'}] pos {pos}  mode {mode}  airborne {tel.airborne if tel else None}  "
        f"wp {tel.waypoints_queued if tel else None}  link {s.link}  manager {'up' if s.manager_up else 'DOWN'}\n"
        f"  tasks: {tasks}\n  modules: {mods}"
    )


def format_error(err: gri.ErrorRecord) -> str:
    """One error: when, which module, its code and name, and what happened."""
    stamp = time.strftime("%H:%M:%S", time.localtime(err.stamp))
    name = err.name or error_name(err.module, err.code)
    return f"{stamp} {err.module:<14} {err.code:>5} {name or '-':<28} {err.detail}".rstrip()


def _print_reply(reply: gri.TaskReply, out: TextIO) -> int:
    if reply.accepted:
        print(f"accepted task {reply.task_id} ({reply.task_type or '-'})", file=out)
        return 0
    code = f" [code {reply.code}]" if reply.code is not None else ""
    print(f"rejected{code}: {reply.reason}", file=out)
    return 1


def _watch(gcs: Gcs, args: argparse.Namespace, out: TextIO) -> int:
    count = 0
    done = threading.Event()
    lock = threading.Lock()
    tty = out.isatty()

    screen = watch_view.WatchScreen(error_name=error_name)

    def show(state: gri.GriState) -> None:
        nonlocal count
        with lock:
            if done.is_set():
                return  # --count reached: states arriving while the watch closes are not printed
            count += 1
            screen.state(state)
            text = "\n".join(screen.lines() if tty else screen.robot(state.robot))
            out.write(("\x1b[H\x1b[J" if tty else "") + text + "\n")
            out.flush()
            if args.count and count >= args.count:
                done.set()

    def event(ev: gri.GriEvent) -> None:
        with lock:
            screen.event(ev)
            if tty or args.events:
                out.write(("\x1b[H\x1b[J" + "\n".join(screen.lines()) if tty else watch_view.event_line(ev)) + "\n")
                out.flush()

    gcs.session.declare_subscriber(watch_view.vision_key(args.robot), lambda smp: screen.vision_status(
        str(smp.key_expr).split("/")[1], msgspec.msgpack.decode(smp.payload.to_bytes())))

    if args.link and args.robot == "*":
        raise UsageError("watch --link needs one robot name: a link is per robot")
    _answering(gcs, args.robot, args.timeout)
    if args.link:  # only on request: a passive watch never arms the robot's link-loss failsafe
        gcs.hold_link(args.robot)
    gcs.watch(args.robot, show)
    gcs.events(args.robot, event)  # the last ones stay on screen
    try:
        while not done.wait(0.2):
            pass
    except KeyboardInterrupt:
        pass
    return 0


def _answering(gcs: Gcs, robot: str, timeout_s: float) -> None:
    """A robot that does not answer is never linked: its failsafe (or another robot's) never counts this station."""
    try:
        gcs.state(robot, timeout_s)
    except NoReply:
        known = ", ".join(gcs.robots(1.0)) or "none"
        raise NoReply(f"no robot {robot!r} answered within {timeout_s:g} s (robots seen: {known})") from None


def _link(gcs: Gcs, args: argparse.Namespace, out: TextIO) -> int:
    """Hold a link (liveliness token + heartbeats naming the robots) and print the robots' link events."""
    for robot in args.robots:
        _answering(gcs, robot, args.timeout)
    lock = threading.Lock()

    def event(ev: gri.GriEvent) -> None:
        if ev.kind in LINK_EVENTS:
            with lock:
                out.write(watch_view.event_line(ev) + "\n")
                out.flush()

    for robot in args.robots:
        gcs.hold_link(robot)
        gcs.events(robot, event)
    print(f"holding a GCS link with {', '.join(args.robots)} as {gcs.name}"
          + (f" for {args.seconds:g} s" if args.seconds > 0 else " (Ctrl-C lets go; the robots' failsafe then "
                                                                   "runs after their failsafe_timeout_s)"), file=out)
    out.flush()
    end = time.monotonic() + args.seconds if args.seconds > 0 else math.inf
    try:
        while time.monotonic() < end:
            time.sleep(min(0.2, max(0.0, end - time.monotonic())))
    except KeyboardInterrupt:
        pass
    return 0


LINK_EVENTS = frozenset({"link_up", "link_lost", "failsafe", "link_regained"})


def run(args: argparse.Namespace, out: TextIO) -> int:
    request = task_request(args) if args.command == "task" else None
    cfg = session_config(
        args.connect,
        ca=args.ca,
        cert=args.cert,
        key=args.key,
        config_file=args.config,
        connect_timeout_s=args.timeout,
    )
    with Gcs(cfg, name=args.name, timeout_s=args.timeout) as gcs:
        if args.command == "robots":
            for robot in gcs.robots():
                print(robot, file=out)
            return 0
        if args.command == "watch":
            return _watch(gcs, args, out)
        if args.command == "link":
            return _link(gcs, args, out)
        if args.command == "task":
            assert request is not None
            return _print_reply(gcs.send(args.robot, request), out)
        if args.command == "abort":
            t0 = time.monotonic()
            code = _print_reply(gcs.abort(args.robot), out)
            print(f"abort answered in {(time.monotonic() - t0) * 1000:.1f} ms", file=out)
            return code
        if args.command == "modules":
            listing = gcs.modules(args.robot)
            print(f"{'module':<16} {'state':<11} {'pid':>7} {'restarts':>8} {'exit':>5}  routes", file=out)
            for m in listing.modules:
                routes = " ".join(f"{k}={v}" for k, v in sorted(m.routes.items())) or "-"
                print(
                    f"{m.name:<16} {m.state:<11} {m.pid or '-':>7} {m.restarts:>8} "
                    f"{'-' if m.last_exit is None else m.last_exit:>5}  {routes}"
                    + (f"  ({m.reason})" if m.reason else ""),
                    file=out,
                )
            return 0
        if args.command == "route":
            routes = gcs.route(args.robot, args.module, args.input, args.slot)
            now = routes.routes.get(args.module, {})
            print(f"{args.module}.{args.input} -> {now.get(args.input, '?')}", file=out)
            return 0
        if args.command == "errors":
            for err in gcs.errors(args.robot):
                print(format_error(err), file=out)
            return 0
        if args.command == "restart":
            return _print_reply(gcs.restart(args.robot, args.module), out)
        if args.command == "fleet":
            return fleet_gcs.run(gcs.session, args, out,
                                  live=gcs.robots() if args.fleet_command == "post" else ())
        if args.command in fleet_cmd.COMMANDS:
            return fleet_cmd.run(gcs, args, out)
    return 2


def main(argv: list[str] | None = None) -> int:
    # what was printed survives a crash of the process (a pipe is block-buffered), and a native crash names the
    # Python frames it happened in: `cromat gcs fleet post` ended once on SIGSEGV with nothing printed (a clean-clone
    # run, not reproduced)
    if hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)
    faulthandler.enable(sys.__stderr__)  # the process's own stderr, also when a caller has captured sys.stderr
    args = build_parser().parse_args(argv)
    try:
        return run(args, sys.stdout)
    except (WaypointFileError, UsageError) as exc:
        print(f"cromat gcs: {exc}", file=sys.stderr)
        return 2
    except (Unreachable, NoReply) as exc:
        print(f"cromat gcs: {exc}", file=sys.stderr)
        return 3
    except GcsError as exc:
        print(f"cromat gcs: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
