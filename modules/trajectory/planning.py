"""Path planning as pure functions in a local east/north frame (metres, bbcs.geodesy.LocalFrame): lawnmower
surveys, orbits, smoothing corners into turns the aircraft can fly. No bus, no clock: tested directly.

Terms:
- **swath**: the ground width the LD-MRS sees across the track, 2·h·tan(half angle) over flat ground
  (the logger scans ±50°);
- **line spacing**: swath × (1 − overlap), so neighbouring swaths share ``overlap`` of their width;
- **lawnmower lower bound**: the sweep lines over the polygon joined by straight connections, turning on
  the spot: no flyable survey of those lines is shorter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

LDMRS_HALF_ANGLE_DEG = 50.0
"""The logger's scan field: +50° to -50° (docs/lidar_logger.md §3)."""
G = 9.80665


class PlanningError(ValueError):
    """A request that cannot be turned into a flyable path; the message says why."""


def swath_width(height: float, half_angle_deg: float = LDMRS_HALF_ANGLE_DEG) -> float:
    return 2.0 * height * math.tan(math.radians(half_angle_deg))


def line_spacing(height: float, overlap: float, half_angle_deg: float = LDMRS_HALF_ANGLE_DEG) -> float:
    if not 0.0 <= overlap < 1.0:
        raise PlanningError(f"overlap must be in [0, 1), got {overlap}")
    if height <= 0:
        raise PlanningError(f"height must be positive, got {height}")
    return swath_width(height, half_angle_deg) * (1.0 - overlap)


def min_turn_radius(speed: float, max_bank_deg: float) -> float:
    """Radius of a coordinated turn at ``speed`` (m/s) and ``max_bank_deg``: v² / (g·tan φ)."""
    if not 0 < max_bank_deg < 90:
        raise PlanningError(f"max bank must be in (0, 90) degrees, got {max_bank_deg}")
    return speed * speed / (G * math.tan(math.radians(max_bank_deg)))


def path_length(points: np.ndarray) -> float:
    p = np.asarray(points, dtype=np.float64)
    return float(np.hypot(*np.diff(p, axis=0).T).sum()) if len(p) > 1 else 0.0


def _check_polygon(polygon: np.ndarray) -> np.ndarray:
    poly = np.asarray(polygon, dtype=np.float64)
    if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 3 or not np.all(np.isfinite(poly)):
        raise PlanningError("a polygon needs at least 3 finite (east, north) vertices")
    if np.allclose(poly[0], poly[-1]):
        poly = poly[:-1]
    area = 0.5 * abs(np.dot(poly[:, 0], np.roll(poly[:, 1], -1)) - np.dot(poly[:, 1], np.roll(poly[:, 0], -1)))
    if area <= 1.0:
        raise PlanningError(f"the polygon encloses {area:.2f} m², nothing to survey")
    return poly


def sweep_lines(polygon: np.ndarray, direction_rad: float, spacing: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Lines along ``direction_rad`` (clockwise from north) across the polygon, ``spacing`` apart and centred
    so the outer swaths reach past its edges; each from the polygon's first to its last crossing (a concave
    gap is flown through). Ordered across the polygon, all in the same direction."""
    poly = _check_polygon(polygon)
    if spacing <= 0:
        raise PlanningError(f"line spacing must be positive, got {spacing}")
    along = np.array([math.sin(direction_rad), math.cos(direction_rad)])
    across = np.array([along[1], -along[0]])
    u, v = poly @ along, poly @ across
    width = v.max() - v.min()
    n = max(1, math.ceil(width / spacing - 1e-9))
    first = v.min() + (width - (n - 1) * spacing) / 2.0
    lines = []
    v2 = np.roll(v, -1)
    u2 = np.roll(u, -1)
    for k in range(n):
        vk = first + k * spacing
        crosses = (v - vk) * (v2 - vk) <= 0
        crosses &= v != v2
        if not crosses.any():
            continue
        t = (vk - v[crosses]) / (v2[crosses] - v[crosses])
        uk = u[crosses] + t * (u2[crosses] - u[crosses])
        a, b = uk.min(), uk.max()
        lines.append((a * along + vk * across, b * along + vk * across))
    return lines


def _serpentine(lines: list[tuple[np.ndarray, np.ndarray]], reverse_order: bool, flip_first: bool,
                extension: float, turn_extension: float = 0.0) -> np.ndarray:
    """Line ends in flying order; every line runs ``extension`` past the polygon, plus ``turn_extension``
    at the ends where the aircraft turns onto the next line (not at the way in and the way out)."""
    order = lines[::-1] if reverse_order else lines
    pts = []
    last = len(order) - 1
    for k, (a, b) in enumerate(order):
        if (k % 2 == 1) != flip_first:
            a, b = b, a
        d = (b - a) / max(np.linalg.norm(b - a), 1e-12)
        pts += [a - d * (extension + (turn_extension if k > 0 else 0.0)),
                b + d * (extension + (turn_extension if k < last else 0.0))]
    return np.array(pts)


@dataclass(frozen=True)
class Survey:
    waypoints: np.ndarray
    """(K, 2) the lawnmower's corners, line ends extended by ``extension``."""
    direction_deg: float
    spacing: float
    lines: int
    lower_bound_m: float
    """Sweep lines over the polygon itself joined straight: the lawnmower lower bound."""


def lawnmower(polygon: np.ndarray, spacing: float, *, direction_deg: float | None = None,
              start: np.ndarray | None = None, extension: float = 0.0, turn_extension: float = 0.0) -> Survey:
    """The boustrophedon over ``polygon``. Without a ``direction_deg``, every edge direction of the polygon
    is tried (the shortest lawnmower runs along one of them); of each, the four ways in (either end line,
    either end of it); the choice minimises the path, plus the leg from ``start`` when given.
    ``turn_extension`` (the turn radius, for a path to be smoothed) makes the turns start past the lines'
    ``extension``, so no part of a line over the polygon is flown banked."""
    poly = _check_polygon(polygon)
    if direction_deg is not None:
        candidates = [math.radians(direction_deg)]
    else:
        edges = np.roll(poly, -1, axis=0) - poly
        candidates = sorted({round(math.atan2(e[0], e[1]) % math.pi, 9) for e in edges if np.hypot(*e) > 0})
    best: tuple[float, Survey] | None = None
    for angle in candidates:
        lines = sweep_lines(poly, angle, spacing)
        if not lines:
            continue
        bound = _serpentine(lines, False, False, 0.0)
        for reverse_order in (False, True):
            for flip in (False, True):
                pts = _serpentine(lines, reverse_order, flip, extension, turn_extension)
                cost = path_length(pts) + (float(np.hypot(*(pts[0] - start))) if start is not None else 0.0)
                if best is None or cost < best[0] - 1e-6:
                    best = (cost, Survey(pts, math.degrees(angle) % 180.0, spacing, len(lines),
                                         path_length(bound)))
    if best is None:
        raise PlanningError("no sweep line crosses the polygon")
    return best[1]


def orbit(centre: np.ndarray, radius: float, *, turns: float = 1.0, clockwise: bool = True,
          start: np.ndarray | None = None, step_deg: float = 5.0) -> np.ndarray:
    """Points on a circle of ``radius`` around ``centre``, ``turns`` times round, starting at the point of
    the circle nearest ``start`` (north of the centre without one), every ``step_deg`` of arc at most."""
    if radius <= 0 or turns <= 0:
        raise PlanningError("an orbit needs a positive radius and number of turns")
    c = np.asarray(centre, dtype=np.float64)
    if start is not None and np.hypot(*(np.asarray(start) - c)) > 1e-9:
        d = np.asarray(start, dtype=np.float64) - c
        theta0 = math.atan2(d[0], d[1])
    else:
        theta0 = 0.0
    steps = max(int(math.ceil(turns * 360.0 / step_deg)), 3)
    sign = 1.0 if clockwise else -1.0  # bearing grows clockwise
    theta = theta0 + sign * np.linspace(0.0, 2 * math.pi * turns, steps + 1)
    return c + radius * np.column_stack((np.sin(theta), np.cos(theta)))


def smooth(points: np.ndarray, radius: float, *, step_deg: float = 10.0) -> np.ndarray:
    """Replace every corner by a circular arc of ``radius`` tangent to both legs, sampled every
    ``step_deg`` at most. A corner whose arc would need more of a leg than is left of it (after the previous
    corner's arc) cannot be flown at that radius: PlanningError naming the corner."""
    p = np.asarray(points, dtype=np.float64)
    keep = np.ones(len(p), dtype=bool)
    keep[1:] = np.hypot(*np.diff(p, axis=0).T) > 1e-9
    p = p[keep]
    if len(p) < 2:
        raise PlanningError("need two distinct waypoints")
    if radius <= 0:
        return p
    out = [p[0]]
    used = 0.0  # length of the incoming leg already taken by the previous arc
    for k in range(1, len(p) - 1):
        a, b, c = p[k - 1], p[k], p[k + 1]
        d_in, d_out = b - a, c - b
        l_in, l_out = float(np.hypot(*d_in)), float(np.hypot(*d_out))
        u_in, u_out = d_in / l_in, d_out / l_out
        cross = u_in[0] * u_out[1] - u_in[1] * u_out[0]
        turn = math.atan2(cross, float(np.dot(u_in, u_out)))
        if abs(turn) < 1e-6:
            used = 0.0
            continue
        if abs(abs(turn) - math.pi) < 1e-6:
            raise PlanningError(f"waypoint {k}: the path doubles back on itself")
        t = radius * math.tan(abs(turn) / 2.0)
        if used + t > l_in + 1e-6 or t > l_out + 1e-6:
            raise PlanningError(f"waypoint {k}: a {math.degrees(abs(turn)):.0f}° turn at radius {radius:.1f} m "
                                f"needs {t:.1f} m of each leg; the legs are {l_in:.1f} m and {l_out:.1f} m")
        p_in = b - u_in * t
        normal = np.array([-u_in[1], u_in[0]]) * math.copysign(1.0, cross)  # towards the turn centre
        centre = p_in + normal * radius
        a0 = math.atan2(*(p_in - centre)[::-1])
        a1 = a0 + turn
        n = max(int(math.ceil(abs(math.degrees(turn)) / step_deg)), 1)
        ang = np.linspace(a0, a1, n + 1)
        out.extend(centre + radius * np.column_stack((np.cos(ang), np.sin(ang))))
        used = t
    out.append(p[-1])
    return np.array(out)
