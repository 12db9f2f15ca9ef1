"""A MAVLink geofence upload as world-model zones (docs/world.md): inclusion polygons become ``Geofence`` entries,
exclusion polygons ``NoFlyZone`` entries, one per polygon, ids ``mavlink.<robot>.fence<N>``.

The world model holds polygons only, so circular fences (``NAV_FENCE_CIRCLE_*``) and return points are refused with
that reason rather than approximated. A polygon's vertices are consecutive items of one command whose ``param1``
is the vertex count (MAVLink's rule). The world model is the fleet's: a zone uploaded through one vehicle applies to
every robot of the fleet, as a ``cromat gcs world add-nfz`` does.
"""

from __future__ import annotations

import msgspec

from bbcs.contracts import world as w
from bbcs.contracts.tasks import Vertex
from cromat.mavlink.dialect import mav
from cromat.mavlink.plan import Item, PlanError, command_name

POLYGON_KINDS = {
    mav.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION: "geofence",
    mav.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION: "no_fly_zone",
}


def fence_id(robot: str, n: int) -> str:
    return f"mavlink.{robot}.fence{n}"


def zones_of(robot: str, items: list[Item], author: str) -> list[w.WorldPut]:
    """One WorldPut per polygon of ``items``; PlanError naming the item that is not a polygon vertex."""
    puts: list[w.WorldPut] = []
    i = 0
    while i < len(items):
        it = items[i]
        kind = POLYGON_KINDS.get(it.command)
        if kind is None:
            raise PlanError(f"fence item {it.seq} ({command_name(it.command)}): the world model holds polygons "
                            "(inclusion = geofence, exclusion = no-fly zone); circles and return points are not mapped")
        n = int(it.param1)
        group = items[i:i + n]
        if n < 3 or len(group) < n or any(g.command != it.command or int(g.param1) != n for g in group):
            raise PlanError(f"fence item {it.seq}: a polygon of {n} vertices needs {n} consecutive items of the same "
                            "kind, each with param1 = the vertex count (at least 3)")
        polygon = [Vertex(lat=g.x / 1e7, lon=g.y / 1e7) for g in group]
        body: w.Body = w.Geofence(polygon=polygon, name=f"mavlink {kind}") if kind == "geofence" else \
            w.NoFlyZone(polygon=polygon, name=f"mavlink {kind}")
        try:
            put = w.WorldPut(id=fence_id(robot, len(puts)), body=body, author=author)
            puts.append(msgspec.convert(msgspec.to_builtins(put), w.WorldPut))
        except msgspec.ValidationError as exc:
            raise PlanError(f"fence item {it.seq}: {exc}") from None
        i += n
    return puts
