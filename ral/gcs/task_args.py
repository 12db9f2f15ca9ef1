"""``cromat gcs task ROBOT KIND ...``, built from the task structs themselves (``bbcs.contracts.gri.TaskRequest``).

A task kind is declared once, as a struct in ``bbcs/contracts/tasks.py``; its command line follows from its fields,
so a new kind needs nothing here. The rules, by field:

* a list of waypoints: a positional ``FILE`` (CSV ``lat,lon,alt`` or GeoJSON, ral/gcs/waypoints.py);
* a list of polygon corners: a positional ``POLYGON.geojson``;
* any other field without a default: a positional argument, in the struct's order;
* a field with a default: ``--field-name`` (``--flag/--no-flag`` for a bool, the choices of a ``Literal``);
* an angle in radians (:data:`bbcs.contracts.geo.Radians`): typed in degrees, wrapped to [-180°, 180°).

:data:`SPELLINGS` keeps a few options as the command line had them before it was generated (``--radius``,
``--counter-clockwise``, ...): each entry changes how one field is typed, never what it means. The ranges stay the
struct's: ``msgspec.convert`` checks them when the request is built, and a refusal names the kind.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from typing import Any

import msgspec
import msgspec.inspect as mi

from bbcs.contracts import gri
from ral.gcs.waypoints import WaypointFileError, load_polygon, load_waypoints

OWN_COMMANDS = frozenset({"abort", "restart_module"})
"""Requests with a command of their own (``cromat gcs abort``, ``cromat gcs restart``), not a task kind."""


@dataclass(frozen=True)
class Spelling:
    """How one field is typed when the generic rule is not how the command line has always spelt it."""

    option: str | None = None
    """The option's name (``--ref-rpm``); a field without a default given this way is a required option."""
    inverted: bool = False
    """A bool typed as a flag that sets it False (``--counter-clockwise`` for ``clockwise``)."""


SPELLINGS: dict[tuple[str, str], Spelling] = {
    ("orbit", "radius"): Spelling(option="--radius"),
    ("orbit", "clockwise"): Spelling(option="--counter-clockwise", inverted=True),
    ("survey", "height"): Spelling(option="--height"),
    ("bridge", "ref_rpm_motor"): Spelling(option="--ref-rpm"),
}


def task_kinds() -> dict[str, type[msgspec.Struct]]:
    """Every request a ground station sends as ``cromat gcs task``: tag → struct."""
    return {str(cls.__struct_config__.tag): cls for cls in gri.TaskRequest.__args__  # type: ignore[attr-defined]
            if str(cls.__struct_config__.tag) not in OWN_COMMANDS}


def _member(t: mi.Type) -> mi.Type:
    """An optional field's type without its ``None`` (``Speed | None`` → ``Speed``, still described)."""
    if isinstance(t, mi.UnionType):
        rest = [x for x in t.types if not isinstance(x, mi.NoneType)]
        if len(rest) == 1:
            return rest[0]
    return t


def _base(t: mi.Type) -> mi.Type:
    """The type without its ``None`` and its description (``Speed | None`` → the float type of ``Speed``)."""
    t = _member(t)
    return t.type if isinstance(t, mi.Metadata) else t


def _unit(t: mi.Type) -> str:
    """The alias's description (``metres above mean sea level``), if it has one."""
    t = _member(t)
    return str((t.extra_json_schema or {}).get("description", "")) if isinstance(t, mi.Metadata) else ""


def _is_list_of(t: mi.Type, name: str) -> bool:
    t = _base(t)
    return (isinstance(t, mi.ListType) and isinstance(t.item_type, mi.StructType)
            and t.item_type.cls.__name__ == name)


def _is_radians(t: mi.Type) -> bool:
    t = _base(t)
    return isinstance(t, mi.FloatType) and t.ge == -math.pi and t.lt == math.pi


def _range(t: mi.Type) -> str:
    t = _base(t)
    if not isinstance(t, mi.FloatType | mi.IntType):
        return ""
    lo = t.ge if t.ge is not None else t.gt
    hi = t.le if t.le is not None else t.lt
    if lo is None and hi is None:
        return ""
    return (f"{'[' if t.ge is not None else '('}{'' if lo is None else f'{lo:g}'}, "
            f"{'' if hi is None else f'{hi:g}'}{']' if t.le is not None else ')'}")


def _scalar(t: mi.Type) -> type:
    t = _base(t)
    return {mi.FloatType: float, mi.IntType: int, mi.StrType: str}.get(type(t), str)  # type: ignore[return-value]


def _add_field(p: argparse.ArgumentParser, kind: str, f: mi.Field) -> None:
    spelling = SPELLINGS.get((kind, f.name), Spelling())
    option = spelling.option or f"--{f.name.replace('_', '-')}"
    default = None if f.default is msgspec.NODEFAULT else f.default
    if _is_list_of(f.type, "Waypoint"):
        p.add_argument(f.name, metavar="FILE", help="waypoints: CSV (lat,lon,alt above sea level) or GeoJSON")
        return
    if _is_list_of(f.type, "Vertex"):
        p.add_argument(f.name, metavar="POLYGON.geojson", help="the area: a GeoJSON Polygon")
        return
    base = _base(f.type)
    if isinstance(base, mi.BoolType):
        if spelling.inverted:
            p.add_argument(option, dest=f.name, action="store_false", help=f"sets {f.name} false")
        else:
            p.add_argument(option, dest=f.name, action=argparse.BooleanOptionalAction, default=default)
        return
    if isinstance(base, mi.LiteralType):
        p.add_argument(option, dest=f.name, choices=[str(v) for v in base.values], default=default,
                       help=f"default {default}")
        return
    if _is_radians(f.type):
        shown = "" if default is None else f" (default {math.degrees(default):g})"
        kw: dict[str, Any] = {"type": float, "metavar": "DEG", "help": f"degrees{shown}"}
        if f.required and spelling.option is None:
            p.add_argument(f.name, **kw)
        else:
            p.add_argument(option, dest=f.name, default=None if default is None else math.degrees(default),
                           required=f.required, **kw)
        return
    shown = f"(default {default:g})" if isinstance(default, float | int) and not isinstance(default, bool) else ""
    help_ = " ".join(x for x in (_unit(f.type), _range(f.type), shown) if x) or None
    if f.required and spelling.option is None:
        p.add_argument(f.name, type=_scalar(f.type), help=help_)
    else:
        p.add_argument(option, dest=f.name, type=_scalar(f.type), default=default, required=f.required,
                       help=help_)


def add_parsers(task: argparse.ArgumentParser, kinds: dict[str, type[msgspec.Struct]] | None = None) -> None:
    """One subcommand per task kind (default: :func:`task_kinds`) under ``cromat gcs task ROBOT``."""
    sub = task.add_subparsers(dest="kind", required=True)
    for kind, cls in (kinds or task_kinds()).items():
        doc = (cls.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
        p = sub.add_parser(kind, help=doc, description=doc)
        for f in mi.type_info(cls).fields:  # type: ignore[attr-defined]
            _add_field(p, kind, f)


def task_request(args: argparse.Namespace, kinds: dict[str, type[msgspec.Struct]] | None = None) -> Any:
    """The request (a :data:`~bbcs.contracts.gri.TaskRequest`) the ``task`` arguments describe; a range the struct
    refuses raises :class:`~ral.gcs.waypoints.WaypointFileError` naming the kind (usage error, exit 2)."""
    kind = args.kind
    cls = (kinds or task_kinds())[kind]
    raw: dict[str, Any] = {"type": kind}
    for f in mi.type_info(cls).fields:  # type: ignore[attr-defined]
        value = getattr(args, f.name)
        if _is_list_of(f.type, "Waypoint"):
            value = [msgspec.to_builtins(w) for w in load_waypoints(value)]
        elif _is_list_of(f.type, "Vertex"):
            value = [msgspec.to_builtins(v) for v in load_polygon(value)]
        elif _is_radians(f.type) and value is not None:
            rad = math.radians(value)
            value = (rad + math.pi) % (2 * math.pi) - math.pi
        raw[f.name] = value
    try:
        request = msgspec.convert(raw, cls)
    except msgspec.ValidationError as exc:
        raise WaypointFileError(f"bad {kind} task: {exc}") from None
    return request
