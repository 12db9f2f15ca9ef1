"""The key-expression scheme, defined in one place.

```
cromat/<robot>/<module>/<slot>          a module's slot
cromat/<robot>/<module>/@schema         queryable: JSON Schemas of the module's slots
cromat/<robot>/<module>/@route          the module's applied routes (acknowledgements)
cromat/<robot>/<module>/@heartbeat      application heartbeat from the module's main loop
cromat/<robot>/@alive/<module>          liveliness token of a running module
cromat/<robot>/@manager/...             Module Manager (MRI) keys
cromat/<robot>/@ral/...                 Robot Abstraction Layer (GRI) keys
```
Chunks starting with ``@`` are verbatim in Zenoh: ``*`` and ``**`` never match them, so a subscriber on
``cromat/r1/**`` sees slot data but not the bus's own bookkeeping.
"""

from __future__ import annotations

import re
from typing import NamedTuple

from bbcs.errors import InvalidNameError

ROOT = "cromat"
_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}")
_FORBIDDEN = set("*$/#?@ \t\r\n")


def validate_name(name: str, what: str = "name") -> str:
    """Return ``name`` if it can stand as one key-expression chunk, else raise InvalidNameError."""
    if not isinstance(name, str) or not name:
        raise InvalidNameError(f"{what} must be a non-empty string, got {name!r}")
    bad = sorted(set(name) & _FORBIDDEN)
    if bad:
        raise InvalidNameError(f"{what} {name!r} contains forbidden character(s) {''.join(bad)!r}")
    if not _NAME.fullmatch(name):
        raise InvalidNameError(
            f"{what} {name!r} must be 1-64 characters of letters, digits, '_', '.', '-' "
            "and must not start with '.' or '-'"
        )
    return name


def _robot_or_wildcard(robot: str) -> str:
    return robot if robot == "*" else validate_name(robot, "robot name")


def module_prefix(robot: str, module: str) -> str:
    """``cromat/<robot>/<module>``."""
    return f"{ROOT}/{validate_name(robot, 'robot name')}/{validate_name(module, 'module name')}"


def slot_key(robot: str, module: str, slot: str) -> str:
    """The key a module's slot is published on."""
    return f"{module_prefix(robot, module)}/{validate_name(slot, 'slot name')}"


def schema_key(robot: str, module: str) -> str:
    return f"{module_prefix(robot, module)}/@schema"


def route_ack_key(robot: str, module: str) -> str:
    return f"{module_prefix(robot, module)}/@route"


def heartbeat_key(robot: str, module: str) -> str:
    return f"{module_prefix(robot, module)}/@heartbeat"


def alive_key(robot: str, module: str) -> str:
    """Liveliness token key of a running module."""
    return f"{ROOT}/{validate_name(robot, 'robot name')}/@alive/{validate_name(module, 'module name')}"


def alive_pattern(robot: str = "*", module: str = "*") -> str:
    """Key expression matching the liveliness tokens of ``module`` (``*``: every module) of ``robot``
    (``*``: all robots)."""
    return f"{ROOT}/{_robot_or_wildcard(robot)}/@alive/{_chunk_or_wildcard(module, 'module name')}"


def manager_key(robot: str, *parts: str) -> str:
    """``cromat/<robot>/@manager/<parts...>``."""
    tail = "/".join(validate_name(p, "manager key part") for p in parts)
    return f"{ROOT}/{_robot_or_wildcard(robot)}/@manager" + (f"/{tail}" if tail else "")


def ral_key(robot: str, *parts: str) -> str:
    """``cromat/<robot>/@ral/<parts...>``; ``robot='*'`` gives a pattern over every robot."""
    tail = "/".join(validate_name(p, "RAL key part") for p in parts)
    return f"{ROOT}/{_robot_or_wildcard(robot)}/@ral" + (f"/{tail}" if tail else "")


# ---------------------------------------------------------------- patterns (access policy, subscriptions)
# Each takes ``*`` (one chunk) wherever a name may be a wildcard; names are validated as in the keys above.


def _chunk_or_wildcard(name: str, what: str) -> str:
    return name if name == "*" else validate_name(name, what)


def slot_pattern(robot: str = "*", module: str = "*", slot: str = "*") -> str:
    """``cromat/<robot>/<module>/<slot>`` with any of the three a ``*``."""
    return (f"{ROOT}/{_robot_or_wildcard(robot)}/{_chunk_or_wildcard(module, 'module name')}/"
            f"{_chunk_or_wildcard(slot, 'slot name')}")


def schema_pattern(robot: str = "*", module: str = "*") -> str:
    """The ``@schema`` queryables of ``module`` (``*``: every module)."""
    return f"{slot_pattern(robot, module, '*').rsplit('/', 1)[0]}/@schema"


def route_ack_pattern(robot: str = "*", module: str = "*") -> str:
    """The ``@route`` acknowledgements of ``module`` (``*``: every module)."""
    return f"{slot_pattern(robot, module, '*').rsplit('/', 1)[0]}/@route"


def heartbeat_pattern(robot: str = "*", module: str = "*") -> str:
    """The ``@heartbeat`` keys of ``module`` (``*``: every module)."""
    return f"{slot_pattern(robot, module, '*').rsplit('/', 1)[0]}/@heartbeat"


def manager_pattern(robot: str = "*") -> str:
    """Every Module Manager key of ``robot``: ``cromat/<robot>/@manager/**``."""
    return f"{manager_key(robot)}/**"


def ral_pattern(robot: str = "*") -> str:
    """Every RAL key of ``robot``: ``cromat/<robot>/@ral/**``."""
    return f"{ral_key(robot)}/**"


def manager_child_pattern(robot: str = "*") -> str:
    """The Module Manager's keys one level down: ``cromat/<robot>/@manager/*`` (its publications)."""
    return f"{manager_key(robot)}/*"


def ral_child_pattern(robot: str = "*") -> str:
    """The RAL's keys one level down: ``cromat/<robot>/@ral/*`` (its publications)."""
    return f"{ral_key(robot)}/*"


def gcs_key(name: str) -> str:
    """``cromat/@gcs/<name>``: a ground station's link token (``*``: every ground station)."""
    return f"{ROOT}/@gcs/{_chunk_or_wildcard(name, 'GCS name')}"


def gcs_pattern() -> str:
    """Every ground-station key: ``cromat/@gcs/**``."""
    return f"{ROOT}/@gcs/**"


def adv_pattern(key: str) -> str:
    """The zenoh.ext advanced pub/sub bookkeeping under ``key`` (``**`` never matches the verbatim ``@adv``)."""
    return f"{key}/@adv/**"


class SlotAddress(NamedTuple):
    robot: str
    module: str
    slot: str


def parse_slot_key(key: str) -> SlotAddress:
    """Split ``cromat/<robot>/<module>/<slot>`` into its names (InvalidNameError if it is not one)."""
    parts = str(key).split("/")
    if len(parts) != 4 or parts[0] != ROOT:
        raise InvalidNameError(f"{key!r} is not a slot key of the form {ROOT}/<robot>/<module>/<slot>")
    robot, module, slot = parts[1:]
    return SlotAddress(
        validate_name(robot, "robot name"), validate_name(module, "module name"), validate_name(slot, "slot name")
    )


def parse_alive_key(key: str) -> tuple[str, str]:
    """Split a liveliness key into ``(robot, module)``."""
    parts = str(key).split("/")
    if len(parts) != 4 or parts[0] != ROOT or parts[2] != "@alive":
        raise InvalidNameError(f"{key!r} is not a liveliness key of the form {ROOT}/<robot>/@alive/<module>")
    return validate_name(parts[1], "robot name"), validate_name(parts[3], "module name")


def schema_key_of(prefix: str) -> str:
    """``<prefix>/@schema``: where a service (``manager_key(robot)``, ``ral_key(robot)``) answers its schemas."""
    return f"{prefix}/@schema"


# ---------------------------------------------------------------- fleet (issue 17: allocation over the bus)


def fleet_task_key(task: str) -> str:
    """``cromat/@fleet/task/<task>``: a fleet task posted by a ground station (``*``: every task)."""
    return f"{ROOT}/@fleet/task/{_chunk_or_wildcard(task, 'fleet task id')}"


def fleet_state_key(robot: str) -> str:
    """``cromat/<robot>/@ral/fleet``: a RAL's fleet state (bids, decisions, tasks known) (``*``: every robot)."""
    return ral_key(robot, "fleet")
