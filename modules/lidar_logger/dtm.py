"""Digital terrain model from georeferenced lidar points: ground selection, a gridded surface, its coverage.

Ground points (``ground_candidates``): points the LD-MRS left unflagged or labelled ground only (its
classification flags, seed enum); dirt on the window, rain/fog clutter and transparent echoes are dropped.

Grid (``build_dtm``): square cells of a user-chosen size, aligned on multiples of the cell size in the ENU
frame. In each cell the **ground filter** fits a plane z = a + b·dx + c·dy by least squares (dx, dy from
the cell centre) and drops the points more than ``max_above`` metres above it (vegetation, objects, late
echoes), three rounds, so the plane sinks from the mean of everything to the ground under it (a tilted
plane, not a height cut, so steep ground is not mistaken for objects); then it drops points whose
residual exceeds ``max(3σ, 5 cm)`` either way (low outliers too) and fits once more. The cell value
is the plane at the cell centre, so a slope does not bias it by where in the cell the points fell, as a mean
would (0.45 slope × 0.5 m = 0.2 m at worst on the simulator's terrain). A cell with ground points that do
not pin a plane (fewer than ``min_points``, or all on one scan line) takes the plane fitted to its 3x3
block of cells at its own centre; a cell with no ground point has no value (NaN): nothing is interpolated
into it.

Coverage (``coverage``): cells with a value over the cells considered (the grid, or those inside a polygon),
and **holes**: connected groups of empty cells enclosed by data (not touching the considered area's edge).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from modules.lidar_logger.flags import FLAG_GROUND

FILTER_ROUNDS = 3


@dataclass(frozen=True)
class Dtm:
    z: np.ndarray
    """(rows, cols) float64 heights, metres, ENU up; NaN = no data. Row 0 is the northern edge."""
    count: np.ndarray
    """(rows, cols) ground points used per cell."""
    west: float
    north: float
    cell: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.z.shape  # type: ignore[return-value]

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """East and north of every cell centre, each (rows, cols)."""
        rows, cols = self.shape
        e = self.west + (np.arange(cols) + 0.5) * self.cell
        n = self.north - (np.arange(rows) + 0.5) * self.cell
        return np.meshgrid(e, n)


@dataclass(frozen=True)
class Coverage:
    cells: int
    with_data: int
    holes: int
    hole_cells: int

    @property
    def percent(self) -> float:
        return 100.0 * self.with_data / self.cells if self.cells else 0.0

    def as_dict(self) -> dict[str, float | int]:
        return {"cells": self.cells, "cells_with_data": self.with_data, "coverage_pct": self.percent,
                "holes": self.holes, "hole_cells": self.hole_cells}


def ground_candidates(flags: np.ndarray) -> np.ndarray:
    """True for points with no flag, or only the ground flag (seed-enum flags)."""
    flags = np.asarray(flags, dtype=np.int64)
    return (flags & ~FLAG_GROUND) == 0


def build_dtm(enu: np.ndarray, cell: float, *, max_above: float = 0.5, min_points: int = 3,
              bounds: tuple[float, float, float, float] | None = None) -> Dtm:
    """Grid ``enu`` (N, 3) ground-candidate points; ``bounds`` = (west, south, east, north), default the
    points' extent snapped outwards to the cell size."""
    if not cell > 0:
        raise ValueError(f"cell size must be positive, got {cell}")
    enu = np.asarray(enu, dtype=np.float64)
    if bounds is None:
        if len(enu) == 0:
            raise ValueError("no ground points to grid")
        west, south = np.floor(enu[:, :2].min(axis=0) / cell) * cell
        east, north = np.ceil(enu[:, :2].max(axis=0) / cell) * cell
    else:
        west, south, east, north = bounds
    cols = max(int(round((east - west) / cell)), 1)
    rows = max(int(round((north - south) / cell)), 1)
    col = np.floor((enu[:, 0] - west) / cell).astype(np.int64)
    row = np.floor((north - enu[:, 1]) / cell).astype(np.int64)
    inside = (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
    col, row, pts = col[inside], row[inside], enu[inside]
    ids = row * cols + col
    n_cells = rows * cols
    dx = pts[:, 0] - (west + (col + 0.5) * cell)
    dy = pts[:, 1] - (north - (row + 0.5) * cell)
    z = pts[:, 2]

    keep = np.ones(len(z), dtype=bool)
    for _ in range(FILTER_ROUNDS):  # points above the plane pull it up less each round: it sinks to the ground
        a, ok = _fit_planes(ids, dx, dy, z, keep, n_cells, min_points, cell)
        keep = ~ok[ids] | (z - _plane_at(a, ids, dx, dy) <= max_above)
    a, ok = _fit_planes(ids, dx, dy, z, keep, n_cells, min_points, cell)
    resid = np.abs(z - _plane_at(a, ids, dx, dy))
    sigma = np.sqrt(np.bincount(ids[keep], weights=resid[keep] ** 2, minlength=n_cells)
                    / np.maximum(np.bincount(ids[keep], minlength=n_cells), 1))
    keep &= ~ok[ids] | (resid <= np.maximum(3 * sigma[ids], 0.05))
    mom = _moments(ids, dx, dy, z, keep, n_cells)
    a, ok = _solve(mom, min_points, cell)
    # a cell whose own points do not pin a plane (too few, or all on one scan line) but has ground points
    # takes the plane through its 3x3 block, evaluated at its own centre
    a3, ok3 = _solve(_neighbourhood(mom, rows, cols, cell), min_points, cell)
    fallback = ~ok & (mom[0] > 0) & ok3
    heights = np.where(ok, a[:, 0], np.where(fallback, a3[:, 0], np.nan)).reshape(rows, cols)
    count = mom[0].astype(np.int64).reshape(rows, cols)
    return Dtm(heights, np.where(np.isfinite(heights), count, 0), float(west), float(north), float(cell))


def _moments(ids: np.ndarray, dx: np.ndarray, dy: np.ndarray, z: np.ndarray, keep: np.ndarray,
             n_cells: int) -> np.ndarray:
    """(9, n_cells) sums n, Σx, Σy, Σxx, Σxy, Σyy, Σz, Σxz, Σyz of the kept points about each cell's centre."""
    i, x, y, h = ids[keep], dx[keep], dy[keep], z[keep]
    weights = (None, x, y, x * x, x * y, y * y, h, x * h, y * h)
    return np.stack([np.bincount(i, weights=w, minlength=n_cells).astype(np.float64) for w in weights])


def _solve(mom: np.ndarray, min_points: int, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares plane per cell from its moments: (n_cells, 3) coefficients, and which cells have a
    well-posed fit (enough points, spread in both directions: the 2x2 covariance not near singular)."""
    n, sx, sy, sxx, sxy, syy, sz, sxz, syz = mom
    m = np.stack([np.stack([n, sx, sy], -1), np.stack([sx, sxx, sxy], -1), np.stack([sy, sxy, syy], -1)], -2)
    rhs = np.stack([sz, sxz, syz], -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cxx = sxx / n - (sx / n) ** 2
        cyy = syy / n - (sy / n) ** 2
        cxy = sxy / n - sx * sy / n**2
        det = cxx * cyy - cxy**2
    ok = (n >= min_points) & (det > (0.01 * cell * cell) ** 2)
    coef = np.zeros((len(n), 3))
    if ok.any():
        coef[ok] = np.linalg.solve(m[ok], rhs[ok][..., None])[..., 0]
    return coef, ok


def _fit_planes(ids: np.ndarray, dx: np.ndarray, dy: np.ndarray, z: np.ndarray, keep: np.ndarray, n_cells: int,
                min_points: int, cell: float) -> tuple[np.ndarray, np.ndarray]:
    return _solve(_moments(ids, dx, dy, z, keep, n_cells), min_points, cell)


def _neighbourhood(mom: np.ndarray, rows: int, cols: int, cell: float) -> np.ndarray:
    """Moments of each cell's 3x3 block about the middle cell's centre (the sums moved to that origin)."""
    n, sx, sy, sxx, sxy, syy, sz, sxz, syz = (m.reshape(rows, cols) for m in mom)
    out = np.zeros((9, rows, cols))
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            ox, oy = dj * cell, -di * cell  # the neighbour's centre seen from the middle one (rows run south)
            src = (slice(max(di, 0), rows + min(di, 0)), slice(max(dj, 0), cols + min(dj, 0)))
            dst = (slice(max(-di, 0), rows + min(-di, 0)), slice(max(-dj, 0), cols + min(-dj, 0)))
            a = [v[src] for v in (n, sx, sy, sxx, sxy, syy, sz, sxz, syz)]
            out[0][dst] += a[0]
            out[1][dst] += a[1] + a[0] * ox
            out[2][dst] += a[2] + a[0] * oy
            out[3][dst] += a[3] + 2 * ox * a[1] + a[0] * ox * ox
            out[4][dst] += a[4] + ox * a[2] + oy * a[1] + a[0] * ox * oy
            out[5][dst] += a[5] + 2 * oy * a[2] + a[0] * oy * oy
            out[6][dst] += a[6]
            out[7][dst] += a[7] + ox * a[6]
            out[8][dst] += a[8] + oy * a[6]
    return out.reshape(9, -1)


def _plane_at(coef: np.ndarray, ids: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    c = coef[ids]
    return c[:, 0] + c[:, 1] * dx + c[:, 2] * dy


def polygon_mask(dtm: Dtm, polygon: np.ndarray) -> np.ndarray:
    """Cells whose centre lies inside ``polygon`` ((K, 2) east, north; even-odd rule)."""
    e, n = dtm.centres()
    poly = np.asarray(polygon, dtype=np.float64)
    inside = np.zeros(e.shape, dtype=bool)
    for (x1, y1), (x2, y2) in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        crosses = (y1 > n) != (y2 > n)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = x1 + (n - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (e < x_at)
    return inside


def coverage(dtm: Dtm, area: np.ndarray | None = None) -> Coverage:
    """Cells with data within ``area`` (a boolean mask; default the whole grid) and the holes in it."""
    area = np.ones(dtm.shape, dtype=bool) if area is None else np.asarray(area, dtype=bool)
    has = np.isfinite(dtm.z) & area
    empty = area & ~has
    # empty cells reachable from the area's edge (or from outside it) are not holes
    rows, cols = dtm.shape
    outside = np.zeros(dtm.shape, dtype=bool)
    queue: deque[tuple[int, int]] = deque()
    padded = np.pad(area, 1, constant_values=False)
    edge = empty & ~(padded[:-2, 1:-1] & padded[2:, 1:-1] & padded[1:-1, :-2] & padded[1:-1, 2:])
    for r, c in zip(*np.nonzero(edge), strict=True):
        outside[r, c] = True
        queue.append((int(r), int(c)))
    while queue:
        r, c = queue.popleft()
        for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
            if 0 <= rr < rows and 0 <= cc < cols and empty[rr, cc] and not outside[rr, cc]:
                outside[rr, cc] = True
                queue.append((rr, cc))
    hole = empty & ~outside
    return Coverage(cells=int(area.sum()), with_data=int(has.sum()), holes=_count_groups(hole),
                    hole_cells=int(hole.sum()))


def _count_groups(mask: np.ndarray) -> int:
    seen = np.zeros(mask.shape, dtype=bool)
    rows, cols = mask.shape
    groups = 0
    for r, c in zip(*np.nonzero(mask), strict=True):
        if seen[r, c]:
            continue
        groups += 1
        seen[r, c] = True
        stack = [(int(r), int(c))]
        while stack:
            y, x = stack.pop()
            for yy, xx in ((y - 1, x), (y + 1, x), (y, x - 1), (y, x + 1)):
                if 0 <= yy < rows and 0 <= xx < cols and mask[yy, xx] and not seen[yy, xx]:
                    seen[yy, xx] = True
                    stack.append((yy, xx))
    return groups


def hillshade(dtm: Dtm, azimuth_deg: float = 315.0, altitude_deg: float = 45.0) -> np.ndarray:
    """uint8 shaded relief (1..255; 0 = no data), light from ``azimuth_deg`` (clockwise from north)."""
    dzde = _slope(dtm.z, dtm.cell, axis=1)
    dzdn = -_slope(dtm.z, dtm.cell, axis=0)  # rows run southwards
    az, alt = np.radians(azimuth_deg), np.radians(altitude_deg)
    light = np.array([np.sin(az) * np.cos(alt), np.cos(az) * np.cos(alt), np.sin(alt)])
    norm = np.sqrt(dzde**2 + dzdn**2 + 1.0)
    shade = (-dzde * light[0] - dzdn * light[1] + light[2]) / norm
    out = np.clip(np.rint(1 + 254 * np.clip(shade, 0, 1)), 1, 255)
    return np.where(np.isfinite(dtm.z), out, 0).astype(np.uint8)


def _slope(z: np.ndarray, cell: float, axis: int) -> np.ndarray:
    """Mean of the differences towards both neighbours along ``axis`` that have data (0 where none has),
    so cells at the edge of the data get a slope too."""
    d = np.diff(z, axis=axis) / cell
    pad = [(0, 0), (0, 0)]
    pad[axis] = (1, 0)
    before = np.pad(d, pad, constant_values=np.nan)
    pad[axis] = (0, 1)
    after = np.pad(d, pad, constant_values=np.nan)
    both = np.stack((before, after))
    count = np.isfinite(both).sum(axis=0)
    total = np.nansum(both, axis=0)
    return np.where(count > 0, total / np.maximum(count, 1), 0.0)


def attitude_rates(pose_time: np.ndarray, euler: np.ndarray) -> np.ndarray:
    """Per scan, the fastest attitude change (deg/s, any axis) around its pose: the larger of the rates to the
    previous and the next distinct pose of the log. The logger logs no angular rates, so this is what the poses
    show; a scan whose pose stands alone (or has no valid time) gets +inf."""
    t = np.asarray(pose_time, dtype=np.float64)
    e = np.asarray(euler, dtype=np.float64)
    rates = np.full(len(t), np.inf)
    ok = np.isfinite(t)
    if ok.sum() < 2:
        return rates
    ts, first = np.unique(t[ok], return_index=True)
    es = e[ok][first]
    if len(ts) < 2:
        return rates
    d = np.diff(es, axis=0)
    d[:, 2] = (d[:, 2] + 180.0) % 360.0 - 180.0  # yaw wraps
    step = np.abs(d).max(axis=1) / np.diff(ts)
    around = np.maximum(np.concatenate(([step[0]], step)), np.concatenate((step, [step[-1]])))
    rates[ok] = around[np.searchsorted(ts, t[ok])]
    return rates
