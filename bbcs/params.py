"""Checking a module's manifest ``params`` (strings) against the struct they configure, every problem at once.

``cromat launch --check`` (module_manager/manifest.py) calls a module class's ``param_errors(params)`` hook and
names each problem with the manifest's file:line; the module itself loads its params with :func:`load_params`
(the same check, raised as a :class:`ParamError`, a ``ConfError``: the module exits with ``EXIT_CONFIG`` and is
not restarted), so the check and the module never disagree. Ranges and choices live in the struct's types.
"""

from __future__ import annotations

import difflib
import enum
from collections.abc import Mapping
from typing import Any, TypeVar

import msgspec

from bbcs.conf import ConfError

S = TypeVar("S", bound=msgspec.Struct)


class ParamError(ConfError, ValueError):
    """A module's manifest parameters are wrong: unknown names, values of the wrong kind, values that clash."""


def _choices(cls: type[msgspec.Struct], key: str) -> str:
    """``(one of: a, b, c)`` for an enum or literal field, else empty."""
    info = msgspec.inspect.type_info(cls)
    field = next((f for f in info.fields if f.name == key), None)  # type: ignore[attr-defined]
    if field is None:
        return ""
    t: Any = field.type
    if isinstance(t, msgspec.inspect.EnumType) and issubclass(t.cls, enum.Enum):
        return f" (one of: {', '.join(str(m.value) for m in t.cls)})"
    if isinstance(t, msgspec.inspect.LiteralType):
        return f" (one of: {', '.join(map(str, t.values))})"
    return ""


def struct_param_errors(cls: type[msgspec.Struct], params: Mapping[str, str], *,
                        what: str) -> list[tuple[str, str]]:
    """(key, reason) for every parameter that is not a field of ``cls`` (with the nearest field named) or whose
    value does not convert to the field's type; empty when ``msgspec.convert(params, cls, strict=False)`` works."""
    fields = tuple(cls.__struct_fields__)
    errors: list[tuple[str, str]] = []
    for key, value in params.items():
        if key not in fields:
            near = difflib.get_close_matches(key, fields, n=1, cutoff=0.75)
            hint = f"did you mean {near[0]}? " if near else ""
            errors.append((key, f"unknown {what} parameter ({hint}known: {', '.join(fields)})"))
            continue
        try:
            msgspec.convert({key: value}, cls, strict=False)
        except msgspec.ValidationError as exc:
            why = str(exc).partition(" - at `")[0]
            errors.append((key, f"bad value {value!r}: {why}{_choices(cls, key)}"))
    return errors


def raise_first(errors: list[tuple[str, str]], *, source: str) -> None:
    """Raise every problem as one :class:`ParamError` (the module's log names them all), or nothing."""
    if errors:
        raise ParamError("; ".join(f"{key}: {reason}" for key, reason in errors), path=source)


def load_params(cls: type[S], params: Mapping[str, str], *, what: str) -> S:
    """``params`` as ``cls`` (every field defaulted), or a :class:`ParamError` naming every problem
    :func:`struct_param_errors` finds: the module's own load, the very check ``cromat launch --check`` runs."""
    raise_first(struct_param_errors(cls, params, what=what), source=f"manifest params of {what}")
    return msgspec.convert(dict(params), cls, strict=False)
