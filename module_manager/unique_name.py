"""Joining the fleet mesh: a robot name must be unique among the robots its peers' routers can see.

The check runs before the robot's own router or any module starts, so a refused launch leaves nothing behind
on the mesh. It asks the peers' routers (a client session) for any liveliness token under ``cromat/<name>/``:
every running module and the manager's bus holds one. A peer that cannot be reached is reported and the launch
goes on, so a robot that boots out of range still flies; two robots started at the very same instant with the
same name are not caught (docs/fleet.md).
"""

from __future__ import annotations

from collections.abc import Callable

from bbcs import SessionConfig, SessionError, TlsConfig, keys, open_session

CHECK_TIMEOUT_S = 3.0


def holders_of(robot: str, peers: list[str], timeout_s: float = CHECK_TIMEOUT_S,
               tls: TlsConfig | None = None) -> list[str] | None:
    """Keys of the liveliness tokens of ``robot`` seen through ``peers``; None when no peer can be reached.
    ``tls``: the certificate to present on ``tls/`` peers (a secured robot asks as its router's identity)."""
    cfg = SessionConfig(mode="client", connect=list(peers), connect_timeout_s=timeout_s, tls=tls)
    try:
        session = open_session(cfg)
    except SessionError:
        return None
    try:
        found = []
        for reply in session.liveliness().get(keys.alive_pattern(robot), timeout=timeout_s):
            if reply.ok is not None:
                found.append(str(reply.ok.key_expr))
        return sorted(found)
    finally:
        session.close()


def duplicate_name_problem(robot: str, peers: list[str], out: Callable[[str], None],
                           timeout_s: float = CHECK_TIMEOUT_S, tls: TlsConfig | None = None) -> str | None:
    """Why ``robot`` must not start (its name is alive on the mesh), or None when it may."""
    held = holders_of(robot, peers, timeout_s, tls)
    if held is None:
        out(f"  mesh        no peer reachable ({', '.join(peers)}): robot name {robot!r} not checked, "
            "starting alone (the router keeps trying its peers)")
        return None
    if held:
        shown = ", ".join(held[:4]) + (" ..." if len(held) > 4 else "")
        return (f"robot name {robot!r} is already alive on the fleet mesh reached through {', '.join(peers)} "
                f"({shown}): robot names must be unique; rename this robot in [robot] name")
    out(f"  mesh        robot name {robot!r} is free on the mesh ({', '.join(peers)})")
    return None
