"""Runtime parameters (``cromat param``, as ``ros2 param``): MRI requests on ``cromat/<robot>/@manager/param``,
the manager's answer, and the manager's request to the module on ``cromat/<robot>/<module>/@params``.

A module class declares its params as one msgspec struct (``params_type``, the very struct it loads its manifest
``params`` into) and which of them it can take while running (``runtime_params``: values it re-reads where they
are used, e.g. the trajectory generator's limits, read per request). Every other parameter is read at start-up
only: setting it is refused with that reason and nothing changes. See docs/tools.md, "cromat param".
"""

from __future__ import annotations

from typing import Any

import msgspec

from bbcs import keys

PARAMS_SUFFIX = "@params"


class ListParams(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    """Every parameter of ``module``: type, range, default, value, settable at run time or why not."""

    module: str


class GetParam(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    module: str
    name: str


class SetParam(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    """Set ``name`` of ``module`` to ``value`` (written as in the manifest: a string, converted by the type)."""

    module: str
    name: str
    value: str


class ParamInfo(msgspec.Struct, frozen=True, kw_only=True):
    name: str
    type: str
    """``float``, ``int``, ``bool``, ``str``, ``one of`` ... as the module declares it; ``str`` when undeclared."""
    value: Any = None
    """The value in force (the manifest's, or the last accepted change)."""
    default: Any = None
    range: str = ""
    """The declared bounds, e.g. ``> 0, < 90`` (empty: none)."""
    choices: list[str] = msgspec.field(default_factory=list)
    settable: bool = False
    """True: the module takes a new value while running."""
    why: str = ""
    """Why it is not settable at run time (empty when it is)."""
    doc: str = ""


class ParamList(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    module: str
    declared: bool
    """False: the module's class declares no parameter struct (its manifest params are listed as strings)."""
    params: list[ParamInfo]


class ParamChange(msgspec.Struct, frozen=True, kw_only=True):
    """One accepted change, as the manager records it in its RobotState (the RAL relays it as a GRI event)."""

    seq: int
    stamp: float
    module: str
    name: str
    old: str
    new: str


class ParamApplied(msgspec.Struct, frozen=True, kw_only=True):
    """The module's answer to a :class:`SetParam`: applied (its new value) or refused and why."""

    ok: bool
    value: Any = None
    reason: str = ""


def module_params_key(robot: str, module: str) -> str:
    """Where a module that takes run-time parameters answers the manager's :class:`SetParam`."""
    return f"{keys.module_prefix(robot, module)}/{PARAMS_SUFFIX}"


def module_params_pattern(robot: str = "*", module: str = "*") -> str:
    """:func:`module_params_key` with the robot or the module a ``*`` (the access policy's rules)."""
    return f"{keys.slot_pattern(robot, module, '*').rsplit('/', 1)[0]}/{PARAMS_SUFFIX}"
