"""``cromat gcs``: the ground-station command line, a thin shell over :mod:`ral.gcs.api`.

Exit codes: 0 done, 1 the robot rejected or refused the request, 2 usage or file error, 3 unreachable, refused
credentials, or no answer.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from typing import TextIO

import msgspec

from cromat.tools.error_names import error_name
from ral import gri
from ral.gcs import watch_view
from ral.gcs.api import Gcs, GcsError, NoReply, Unreachable, UsageError, session_config
from ral.gcs.waypoints import WaypointFileError, load_waypoints


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cromat gcs", description="Ground control station for cromat robots.")
    p.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="robot router endpoint, e.g. tls/robot1:7447 (repeatable; default tcp/127.0.0.1:7447)",
    )
    p.add_argument("--ca", help="CA certificate (PEM) that signed the router's certificate (tls/)")
    p.add_argument("--cert", help="this station's certificate (PEM) for mutual TLS")
    p.add_argument("--key", help="this station's private key (PEM)")
    p.add_argument("--config", metavar="FILE", help="Zenoh JSON5 config file (applied first)")
    p.add_argument("--name", default="gcs", help="station name (liveliness token), default gcs")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for answers (default 5)")
    sub = p.add_subparsers(dest="command", required=True)
    sub.add_parser("robots", help="list live robots")
    w = sub.add_parser("watch", help="live robot state, refreshed in place; holds a GCS link")
    w.add_argument("robot", help="robot name, or '*' for every robot behind the router")
    w.add_argument("--count", type=int, default=0, help="stop after this many states (0: until Ctrl-C)")
    w.add_argument("--events", action="store_true", help="piped: also print events (a terminal shows the last ones)")
    t = sub.add_parser("task", help="submit a task")
    t.add_argument("robot")
    kinds = t.add_subparsers(dest="kind", required=True)
    k = kinds.add_parser("take_off")
    k.add_argument("--height", type=float, default=10.0)
    kinds.add_parser("land")
    kinds.add_parser("hold")
    kinds.add_parser("track", help="pan & tilt follows the perception module's target")
    for name in ("goto", "follow_path"):
        k = kinds.add_parser(name, help="waypoints from a CSV (lat,lon,alt) or GeoJSON file")
        k.add_argument("file")
        k.add_argument("--speed", type=float)
    k = kinds.add_parser("look_at")
    k.add_argument("lat", type=float)
    k.add_argument("lon", type=float)
    k.add_argument("alt", type=float)
    k = kinds.add_parser("pan_tilt")
    k.add_argument("pan", type=float)
    k.add_argument("tilt", type=float)
    k = kinds.add_parser("cancel")
    k.add_argument("task_type")
    a = sub.add_parser("abort", help="stop every task of a robot now")
    a.add_argument("robot")
    m = sub.add_parser("modules", help="module health, restarts and routes")
    m.add_argument("robot")
    r = sub.add_parser("route", help="swap a module's input to another slot number (-1: ignore)")
    r.add_argument("robot")
    r.add_argument("module")
    r.add_argument("input")
    r.add_argument("slot", type=int)
    e = sub.add_parser("errors", help="a robot's most recent errors")
    e.add_argument("robot")
    return p


def task_request(args: argparse.Namespace) -> gri.TaskRequest:
    """The GRI request the ``task`` arguments describe (msgspec validates ranges)."""
    import msgspec

    kind = args.kind
    if kind in ("goto", "follow_path"):
        raw: dict = {
            "type": kind,
            "waypoints": [msgspec.to_builtins(w) for w in load_waypoints(args.file)],
            "speed": args.speed,
        }
    elif kind == "take_off":
        raw = {"type": kind, "height": args.height}
    elif kind == "look_at":
        raw = {"type": kind, "lat": args.lat, "lon": args.lon, "alt": args.alt}
    elif kind == "pan_tilt":
        raw = {"type": kind, "pan": args.pan, "tilt": args.tilt}
    elif kind == "cancel":
        raw = {"type": kind, "task_type": args.task_type}
    else:
        raw = {"type": kind}
    try:
        return msgspec.convert(raw, gri.TaskRequest)
    except msgspec.ValidationError as exc:
        raise WaypointFileError(f"bad {kind} task: {exc}") from None


def format_state(s: gri.GriState) -> str:
    pos = f"{s.position.lat:.6f} {s.position.lon:.6f} {s.position.alt:.1f} m" if s.position else "unknown"
    tasks = ", ".join(f"{t.task_type}:{t.kind}#{t.id}" for t in s.tasks) or "none"
    mods = " ".join(f"{m.name}={m.state}" for m in s.modules) or "-"
    return (
        f"{s.robot} [{s.kind or '?'}] pos {pos}  mode {s.mode_name or s.mode}  airborne {s.airborne}  "
        f"wp {s.waypoints_queued}  link {s.link}  manager {'up' if s.manager_up else 'DOWN'}\n"
        f"  tasks: {tasks}\n  modules: {mods}"
    )


def _print_reply(reply: gri.TaskReply, out: TextIO) -> int:
    if reply.accepted:
        print(f"accepted task {reply.task_id} ({reply.task_type or '-'})", file=out)
        return 0
    print(f"rejected: {reply.reason}", file=out)
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

    gcs.watch(args.robot, show)
    gcs.events(args.robot, event)  # the last ones stay on screen
    try:
        while not done.wait(0.2):
            pass
    except KeyboardInterrupt:
        pass
    return 0


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
    with Gcs(cfg, name=args.name, link=args.command == "watch", timeout_s=args.timeout) as gcs:
        if args.command == "robots":
            for robot in gcs.robots():
                print(robot, file=out)
            return 0
        if args.command == "watch":
            return _watch(gcs, args, out)
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
                stamp = time.strftime("%H:%M:%S", time.localtime(err.stamp))
                print(f"{stamp} {err.source:<14} {err.code:>5}  {err.detail}", file=out)
            return 0
    return 2


def main(argv: list[str] | None = None) -> int:
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
