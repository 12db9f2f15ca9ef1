"""``cromat launch MANIFEST``: check the manifest, start the robot (router, processes, modules), supervise it,
and stop every child on Ctrl+C / SIGTERM."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bbcs import forward_stop_signals
from module_manager.lockstep import parse_speed
from module_manager.manager import LaunchError, Manager
from module_manager.manifest import ManifestError, load_manifest


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cromat launch", description="Start and supervise a robot from a manifest.")
    p.add_argument("manifest", help="launch manifest (.toml), e.g. bbcs_conf/uav1_sim.toml")
    p.add_argument("--once-up", action="store_true",
                   help="stop everything and exit 0 as soon as every module is up (benchmarks, smoke tests)")
    p.add_argument("--status-interval", type=float, default=0.0, metavar="S",
                   help="print every module's status line every S seconds once up (0: only on changes)")
    p.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help="router endpoint instead of the manifest's bus.listen (repeatable)")
    p.add_argument("--log-dir", metavar="DIR", help="write each child's stdout/stderr to DIR/<name>.log")
    p.add_argument("--check", action="store_true", help="only check the manifest, start nothing")
    p.add_argument("--speed", metavar="max|N",
                   help="a lockstep simulation ([sim] lockstep = true) at most N times real time, or as fast as the "
                        "modules allow ('max'); default: the manifest's [sim] speed (docs/simulation.md)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        manifest = load_manifest(args.manifest)
    except ManifestError as exc:
        print(f"cromat launch: manifest error: {exc}", file=sys.stderr)
        return 2
    speed: float | str | None = None
    if args.speed is not None:
        try:
            speed = parse_speed(args.speed)
        except ValueError as exc:
            print(f"cromat launch: {exc}", file=sys.stderr)
            return 2
        if not manifest.raw.sim.lockstep:
            print(f"cromat launch: --speed needs a lockstep simulation: {args.manifest} has no [sim] lockstep = true",
                  file=sys.stderr)
            return 2
    if args.check:
        print(f"{args.manifest}: ok ({len(manifest.modules)} modules, {len(manifest.slot_table.slots)} slots, "
              f"{len(manifest.tasks)} tasks)")
        return 0
    try:
        manager = Manager(manifest, listen=args.listen, log_dir=Path(args.log_dir) if args.log_dir else None,
                          speed=speed)
    except LaunchError as exc:
        print(f"cromat launch: {exc}", file=sys.stderr)
        return 2

    restore_signals = forward_stop_signals(lambda _signum: manager.stop_event.set())  # never a lock in a handler
    try:
        return manager.run(once_up=args.once_up, status_interval=args.status_interval)
    finally:
        restore_signals()


if __name__ == "__main__":
    raise SystemExit(main())
