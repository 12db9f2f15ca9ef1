"""Plane geometry on WGS84 points for the world model's rules: inside a polygon, a leg crossing one.

Points are projected on a local tangent plane (bbcs.geodesy's WGS84 scale at a reference latitude): metres-accurate
over the few kilometres a zone or a flight spans, which is what these checks need.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from bbcs.geodesy import local_en, offset

LatLon = tuple[float, float]
XY = tuple[float, float]


def project(points: Sequence[LatLon], lat0: float, lon0: float) -> list[XY]:
    """(lat, lon) → (east, north) metres from (lat0, lon0)."""
    return [local_en(lat0, lon0, lat, lon) for lat, lon in points]


def unproject(x: float, y: float, lat0: float, lon0: float) -> LatLon:
    """(east, north) metres from (lat0, lon0) → (lat, lon): the inverse of :func:`project`."""
    return offset(lat0, lon0, y, x)


def inside(p: XY, poly: Sequence[XY]) -> bool:
    """Ray casting; a point on an edge counts as inside (a waypoint on a zone's border is refused)."""
    x, y = p
    hit = False
    n = len(poly)
    for i in range(n):
        (x1, y1), (x2, y2) = poly[i], poly[(i + 1) % n]
        if _on_segment(p, (x1, y1), (x2, y2)):
            return True
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            hit = not hit
    return hit


def _cross(o: XY, a: XY, b: XY) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _on_segment(p: XY, a: XY, b: XY, eps: float = 1e-6) -> bool:
    return (abs(_cross(a, b, p)) <= eps * max(1.0, math.dist(a, b))
            and min(a[0], b[0]) - eps <= p[0] <= max(a[0], b[0]) + eps
            and min(a[1], b[1]) - eps <= p[1] <= max(a[1], b[1]) + eps)


def segments_cross(a: XY, b: XY, c: XY, d: XY) -> bool:
    """Do segments ab and cd touch or cross?"""
    d1, d2, d3, d4 = _cross(c, d, a), _cross(c, d, b), _cross(a, b, c), _cross(a, b, d)
    if ((d1 > 0) != (d2 > 0) and d1 != 0 and d2 != 0) and ((d3 > 0) != (d4 > 0) and d3 != 0 and d4 != 0):
        return True
    return any(_on_segment(p, s, e) for p, s, e in ((a, c, d), (b, c, d), (c, a, b), (d, a, b)))


def leg_enters(a: XY, b: XY, poly: Sequence[XY]) -> bool:
    """Does the straight leg a→b pass through the polygon (an end inside, or an edge crossed)?"""
    if inside(a, poly) or inside(b, poly):
        return True
    n = len(poly)
    return any(segments_cross(a, b, poly[i], poly[(i + 1) % n]) for i in range(n))


def polygons_overlap(p: Sequence[XY], q: Sequence[XY]) -> bool:
    """Do two polygons share any area or border?"""
    if any(inside(v, q) for v in p) or any(inside(v, p) for v in q):
        return True
    return any(segments_cross(p[i], p[(i + 1) % len(p)], q[j], q[(j + 1) % len(q)])
               for i in range(len(p)) for j in range(len(q)))


def circle(lat: float, lon: float, radius_m: float, n: int = 32) -> list[LatLon]:
    """A circle as an ``n``-gon that contains it (vertices pushed out so the edges stay outside the circle)."""
    r = radius_m / math.cos(math.pi / n)
    return [unproject(r * math.sin(a), r * math.cos(a), lat, lon) for a in (2 * math.pi * i / n for i in range(n))]
