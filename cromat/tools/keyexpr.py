"""Key expressions the tools subscribe to, made from the scheme in :mod:`bbcs.keys`.

``*`` and ``**`` never match ``@`` chunks, so "everything of a robot" is its slots plus the bookkeeping keys a
tool should see (GRI state and events, the manager's robot state, route acknowledgements, heartbeats).
"""

from __future__ import annotations

from bbcs import keys


def robot_pattern(robot: str) -> str:
    return robot if robot == "*" else keys.validate_name(robot, "robot name")


def slot_pattern(robot: str = "*") -> str:
    """Every module slot of ``robot``: ``cromat/<robot>/*/*``."""
    return keys.slot_pattern(robot_pattern(robot))


def everything(robot: str = "*") -> list[str]:
    """Slots plus the bookkeeping a recording needs to replay a flight into a ground station."""
    r = robot_pattern(robot)
    return [slot_pattern(robot), keys.ral_child_pattern(r), keys.manager_key(r, "state"), keys.route_ack_pattern(r),
            keys.heartbeat_pattern(r)]


def expand(selection: str) -> str:
    """A user's selection: a key expression, or the short ``robot/module/slot`` form without ``cromat/``."""
    sel = selection.strip().strip("/")
    if not sel.startswith(keys.ROOT + "/") and sel != keys.ROOT and sel != "**":
        sel = f"{keys.ROOT}/{sel}"
    return sel


def intersects(pattern: str, key: str) -> bool:
    import zenoh

    return zenoh.KeyExpr(pattern).intersects(zenoh.KeyExpr(key))


def remap_robot(key: str, old: str, new: str) -> str:
    """``cromat/<old>/...`` → ``cromat/<new>/...`` (other keys unchanged)."""
    parts = key.split("/")
    if len(parts) > 1 and parts[0] == keys.ROOT and parts[1] == old:
        parts[1] = keys.validate_name(new, "robot name")
    return "/".join(parts)
