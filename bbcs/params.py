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


# ---------------------------------------------------------------- run-time parameters (cromat param)

STARTUP_ONLY = "read at start-up only"


def _type_text(t: Any) -> tuple[str, str, list[str]]:
    """(type, range, choices) of a field's msgspec type, as ``cromat param list`` shows them."""
    if isinstance(t, msgspec.inspect.Metadata):
        t = t.type
    if isinstance(t, msgspec.inspect.EnumType):
        return "one of", "", [str(m.value) for m in t.cls]
    if isinstance(t, msgspec.inspect.LiteralType):
        return "one of", "", [str(v) for v in t.values]
    bounds = [f"{op} {getattr(t, attr):g}" for attr, op in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="))
              if getattr(t, attr, None) is not None]
    names = {msgspec.inspect.FloatType: "float", msgspec.inspect.IntType: "int", msgspec.inspect.BoolType: "bool",
             msgspec.inspect.StrType: "str"}
    return names.get(type(t), type(t).__name__.removesuffix("Type").lower()), ", ".join(bounds), []


def startup_reason(module: str, name: str) -> str:
    return (f"{module}.{name} is {STARTUP_ONLY}: change modules.{module}.params.{name} in the manifest and restart "
            f"{module}")


def describe_params(module: str, cls: type[msgspec.Struct] | None, values: Mapping[str, str],
                    runtime: frozenset[str]) -> list[Any]:
    """Every parameter of ``module`` as :class:`bbcs.contracts.params.ParamInfo`: the declared struct's fields with
    their values in force (``values``, strings as in the manifest), or, undeclared, the manifest's strings."""
    from bbcs.contracts.params import ParamInfo

    if cls is None:
        why = (f"module {module} declares no parameter struct: its params are {STARTUP_ONLY} (change the manifest "
               f"and restart {module})")
        return [ParamInfo(name=k, type="str", value=v, why=why) for k, v in values.items()]
    try:
        current = msgspec.to_builtins(load_params(cls, values, what=module))
    except ParamError:
        current = {}
    out = []
    for f in msgspec.inspect.type_info(cls).fields:  # type: ignore[attr-defined]
        type_, range_, choices = _type_text(f.type)
        default = None if f.default is msgspec.NODEFAULT else msgspec.to_builtins(f.default)
        out.append(ParamInfo(name=f.name, type=type_, value=current.get(f.name, values.get(f.name)),
                             default=default, range=range_, choices=choices, settable=f.name in runtime,
                             why="" if f.name in runtime else startup_reason(module, f.name)))
    return out


def check_set(module: str, cls: type[msgspec.Struct] | None, runtime: frozenset[str], name: str,
              value: str) -> str:
    """Why ``module.name = value`` cannot be set now ('' when it can): undeclared, unknown, start-up only, or a
    value that does not convert to the field's type and range."""
    if cls is None:
        return (f"module {module} declares no parameter struct: its params are {STARTUP_ONLY} (change the manifest "
                f"and restart {module})")
    errors = struct_param_errors(cls, {name: value}, what=module)
    if errors and name not in cls.__struct_fields__:
        return f"{module}.{name}: {errors[0][1]}"
    if name not in runtime:
        return startup_reason(module, name)
    if errors:
        return f"{module}.{name}: {errors[0][1]}"
    return ""


def with_value(current: S, name: str, value: str) -> S:
    """``current`` with ``name`` set from its string (checked first with :func:`check_set`)."""
    field = getattr(msgspec.convert({name: value}, type(current), strict=False), name)
    return msgspec.structs.replace(current, **{name: field})


class ParamServer:
    """A module's side of ``cromat param set``: answers the manager's :class:`bbcs.contracts.params.SetParam` on
    ``cromat/<robot>/<module>/@params``; the new value is applied on the module's event loop (``apply``, in order
    with its inputs), and the answer sent once it has been.

    ``module`` is the running :class:`bbcs.module.Module` (its session, ``call_soon``); ``current`` gives the
    struct in force; only names in ``runtime`` are taken."""

    def __init__(self, module: Any, current: Any, apply: Any, runtime: frozenset[str],
                 timeout_s: float = 5.0) -> None:
        from bbcs.contracts.params import module_params_key

        self.module = module
        self.current = current
        self.apply = apply
        self.runtime = runtime
        self.timeout_s = timeout_s
        self.queryable = module.session.declare_queryable(module_params_key(module.robot, module.module),
                                                         self._on_query)

    def _on_query(self, query: Any) -> None:
        import threading

        from bbcs.contracts.params import ParamApplied, SetParam

        try:
            req = msgspec.msgpack.decode(query.payload.to_bytes() if query.payload is not None else b"",
                                         type=SetParam)
        except msgspec.MsgspecError as exc:
            query.reply(query.key_expr, msgspec.msgpack.encode(ParamApplied(ok=False, reason=f"unreadable: {exc}")))
            return
        current = self.current()
        why = check_set(self.module.module, type(current), self.runtime, req.name, req.value)
        if why:
            query.reply(query.key_expr, msgspec.msgpack.encode(ParamApplied(ok=False, reason=why)))
            return
        new = with_value(current, req.name, req.value)
        done = threading.Event()
        failed: list[str] = []

        def run() -> None:
            try:
                self.apply(new)
            except Exception as exc:  # the module refused it: its old value stays (apply changes nothing then)
                failed.append(f"{type(exc).__name__}: {exc}")
            finally:
                done.set()

        self.module.call_soon(run)
        if done.wait(self.timeout_s):
            answer = (ParamApplied(ok=False, reason=f"the module refused it: {failed[0]}") if failed
                      else ParamApplied(ok=True, value=msgspec.to_builtins(getattr(new, req.name))))
        else:
            answer = ParamApplied(ok=False, reason=f"the module's loop did not take it within {self.timeout_s:g} s")
        query.reply(query.key_expr, msgspec.msgpack.encode(answer))
