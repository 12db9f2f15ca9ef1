"""What a module process is told when it starts: robot, instance name, bus, slot table, routes, restarts.

The Module Manager passes it as JSON in the ``CROMAT_CONTEXT`` environment variable; a module started by hand
gets the same from command-line options (``--robot``, ``--name``, ``--connect``, ``--slot-table``, ...).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import msgspec

from bbcs.routing import SlotTable
from bbcs.session import SessionConfig

CONTEXT_ENV = "CROMAT_CONTEXT"


class ModuleContext(msgspec.Struct, frozen=True, kw_only=True):
    """Everything a module needs to join its robot's bus."""

    robot: str
    module: str
    """Instance name: the key chunk of this module's slots (``cromat/<robot>/<module>/...``)."""
    bus: SessionConfig = msgspec.field(default_factory=SessionConfig)
    slot_table: SlotTable | None = None
    routes: dict[str, int] = msgspec.field(default_factory=dict)
    """Initial route of each routed input (input slot name → slot number); CONTROL_ENTRADA overrides it."""
    conf: str | None = None
    """Path of the robot's .conf file."""
    params: dict[str, str] = msgspec.field(default_factory=dict)
    """Module-specific arguments from the manifest (``--param key=value`` by hand)."""
    restart_count: int = 0
    """How many times the manager restarted this module (0 on the first start)."""


def encode_context(ctx: ModuleContext) -> str:
    return msgspec.json.encode(ctx).decode()


def decode_context(text: str) -> ModuleContext:
    return msgspec.json.decode(text, type=ModuleContext)


def context_parser(prog: str, default_name: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=f"Run the {default_name} module.")
    p.add_argument("--robot", default="uav1", help="robot name (default uav1)")
    p.add_argument("--name", default=default_name, help=f"module instance name (default {default_name})")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="router endpoint (repeatable), default tcp/127.0.0.1:7447")
    p.add_argument("--bus", metavar="JSON", help="full bus SessionConfig as JSON (overrides --connect)")
    p.add_argument("--slot-table", metavar="FILE", help="slot table as JSON {robot, slots: {n: {module, slot, type}}}")
    p.add_argument("--route", action="append", default=[], metavar="INPUT=N", help="initial route of an input")
    p.add_argument("--conf", metavar="FILE", help="robot .conf file")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE", help="module parameter")
    return p


def _pairs(items: list[str], what: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise SystemExit(f"{what} must be KEY=VALUE, got {item!r}")
        out[key] = value
    return out


def load_context(argv: list[str] | None, prog: str, default_name: str) -> ModuleContext:
    """The context from ``CROMAT_CONTEXT`` (the manager's way) and/or ``argv``.

    With both, the manager's context is the base and ``--param``/``--route``/``--conf`` given on the command line
    are added on top (a manifest can pass extra arguments this way).
    """
    env = os.environ.get(CONTEXT_ENV)
    if env:
        base = decode_context(env)
        if not argv:
            return base
        extra = context_parser(prog, default_name).parse_args(argv)
        return msgspec.structs.replace(
            base, params={**base.params, **_pairs(extra.param, "--param")},
            routes={**base.routes, **{k: int(v) for k, v in _pairs(extra.route, "--route").items()}},
            conf=extra.conf or base.conf)
    args = context_parser(prog, default_name).parse_args(argv)
    if args.bus:
        bus = msgspec.json.decode(args.bus, type=SessionConfig)
    else:
        bus = SessionConfig(connect=args.connect or ["tcp/127.0.0.1:7447"])
    table = None
    if args.slot_table:
        table = msgspec.json.decode(Path(args.slot_table).read_bytes(), type=SlotTable)
    routes = {k: int(v) for k, v in _pairs(args.route, "--route").items()}
    return ModuleContext(robot=args.robot, module=args.name, bus=bus, slot_table=table, routes=routes,
                         conf=args.conf, params=_pairs(args.param, "--param"))
