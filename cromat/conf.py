"""``cromat conf check FILE``: every mistake in a robot .conf, each as ``file:line:col: message``; exit 1 if any.

The file's syntax is checked by :mod:`bbcs.conf`; its values by the modules that read it: every module class
with a ``conf_errors(doc) -> list[ConfError]`` attribute (e.g. ``modules.dsp.module:DspModule``). Which classes:
those of ``--manifest`` (the same check ``cromat launch --check`` runs), those given with ``--class``, or by
default those of every manifest beside the file that names it as its ``robot.conf`` (``bbcs_conf/uquad1.conf`` is
checked by ``uquad1_sim.toml``'s modules); with no such manifest, the UAV's modules (DSP, lidar logger, RAL).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bbcs import ConfDocument, ConfError, load_conf

DEFAULT_CLASSES = ("modules.dsp.module:DspModule", "modules.lidar_logger.module:LidarLoggerModule",
                   "ral.module:Ral")
"""The module classes whose .conf part ``cromat conf check FILE`` checks when no manifest beside it names the file
(the UAV's: its DSP, the lidar logger's group and the RAL's limits)."""

Checker = Callable[[ConfDocument], list[ConfError]]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cromat conf", description="Check a robot .conf file.")
    sub = p.add_subparsers(dest="command", required=True)
    check = sub.add_parser("check", help="report every error of a robot .conf with file:line")
    check.add_argument("file", help="robot .conf, e.g. bbcs_conf/uav1.conf")
    group = check.add_mutually_exclusive_group()
    group.add_argument("--manifest", help="check with the module classes of this launch manifest (.toml)")
    group.add_argument("--class", dest="classes", action="append", metavar="PKG.MOD:CLASS",
                       help="check with this module class (repeatable)")
    return p


def manifest_classes(path: Path, raw: dict[str, Any] | None = None) -> list[str]:
    """The ``class`` of every module of a manifest (``raw``: its TOML already read); its ``pythonpath`` folders go on
    ``sys.path``."""
    if raw is None:
        raw = tomllib.loads(path.read_text())
    for folder in raw.get("pythonpath", []):
        entry = str((path.parent / folder).resolve())
        if entry not in sys.path:
            sys.path.insert(0, entry)
    return [spec["class"] for spec in raw.get("modules", {}).values() if "class" in spec]


def neighbour_manifests(conf: Path) -> list[tuple[Path, dict[str, Any]]]:
    """The manifests in the .conf's folder whose ``[robot] conf`` is that file, each with its TOML (unreadable ones
    are skipped: checking a .conf must not fail on another file)."""
    found = []
    for manifest in sorted(conf.parent.glob("*.toml")):
        try:
            raw = tomllib.loads(manifest.read_text())
        except (OSError, tomllib.TOMLDecodeError):
            continue
        named = raw.get("robot", {}).get("conf")
        if isinstance(named, str) and (manifest.parent / named).resolve() == conf.resolve():
            found.append((manifest, raw))
    return found


def default_classes(conf: Path) -> list[str]:
    """The module classes of the manifests beside ``conf`` that name it; ``DEFAULT_CLASSES`` if none does."""
    classes: list[str] = []
    for manifest, raw in neighbour_manifests(conf):
        classes += [c for c in manifest_classes(manifest, raw) if c not in classes]
    return classes or list(DEFAULT_CLASSES)


def checkers(classes: list[str] | tuple[str, ...]) -> dict[str, Checker]:
    """``class name → conf_errors`` of every class that declares one."""
    out: dict[str, Checker] = {}
    for name in classes:
        module_name, _, qualname = name.partition(":")
        obj: Any = importlib.import_module(module_name)
        for part in qualname.split("."):
            obj = getattr(obj, part)
        check = getattr(obj, "conf_errors", None)
        if callable(check):
            out[name] = check
    return out


def check_file(path: str | Path, classes: list[str] | tuple[str, ...] = DEFAULT_CLASSES) -> list[ConfError]:
    """Every error of the .conf at ``path``: its syntax error, or every value error the classes find."""
    try:
        doc = load_conf(path)
    except ConfError as exc:
        return [exc]
    errors = {str(e): e for check in checkers(classes).values() for e in check(doc)}  # two modules, one key: once
    return sorted(errors.values(), key=lambda e: (e.line or 0, e.column or 0))


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        classes = (manifest_classes(Path(args.manifest)) if args.manifest
                   else args.classes or default_classes(Path(args.file)))
        found = checkers(classes)
    except (OSError, tomllib.TOMLDecodeError, ImportError, AttributeError) as exc:
        print(f"cromat conf: {exc}", file=sys.stderr)
        return 2
    errors = check_file(args.file, classes)
    for error in errors:
        print(error, file=sys.stderr)
    if errors:
        print(f"{args.file}: {len(errors)} error(s) (checked by {', '.join(found) or 'syntax only'})", file=sys.stderr)
        return 1
    print(f"{args.file}: ok (checked by {', '.join(found) or 'syntax only'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
