"""What the simulated camera looks at: a procedural ground texture and moving targets, in a local ENU frame.

The texture is a pure function of ground coordinates and a seed (integer hashing, no stored image), so
any view of it is reproducible. The colour of each cell within ``TABLE_HALF_CELLS`` of the origin is computed once,
on first use, and looked up after that: the simulated camera renders every frame of every simulated flight, and
hashing each pixel again was most of the vision module's processor time. Cells farther out are computed per pixel,
the same values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

RGB = tuple[int, int, int]
TABLE_HALF_CELLS = 256
"""Cells looked up, not hashed: ``[-256, 256)`` on both axes, 1 km square with 2 m cells (3 MB of float32)."""


def _hash2(ix: NDArray[np.int32], iy: NDArray[np.int32], seed: int) -> NDArray[np.float32]:
    """Deterministic per-cell value in [0, 1) from integer cell indices (32-bit integer mixing)."""
    h = ix.astype(np.uint32) * np.uint32(0x8DA6B343)
    h ^= iy.astype(np.uint32) * np.uint32(0xD8163841)
    h ^= np.uint32((seed * 0x9E3779B1) & 0xFFFFFFFF)
    h ^= h >> np.uint32(13)
    h *= np.uint32(0x5BD1E995)
    h ^= h >> np.uint32(15)
    return (h >> np.uint32(8)).astype(np.float32) * np.float32(1.0 / (1 << 24))


@dataclass(frozen=True)
class GroundTexture:
    """Fields of ``field_m`` metres with varying tint, overlaid by a ``cell_m`` checker with per-cell noise.

    Colours are muted greens/browns (red minus max(green, blue) stays below about 50), so the texture
    never looks like a saturated coloured target.
    """

    seed: int = 0
    cell_m: float = 2.0
    field_m: float = 16.0
    light: RGB = (118, 128, 82)
    dark: RGB = (78, 100, 58)
    noise: float = 30.0

    def colour(self, east: NDArray[np.floating], north: NDArray[np.floating]) -> NDArray[np.float32]:
        """RGB float32 (..., 3) in [0, 255] for ground points (same shape arrays)."""
        ix = np.floor(east / np.float32(self.cell_m)).astype(np.int32)
        iy = np.floor(north / np.float32(self.cell_m)).astype(np.int32)
        table = self._table
        if table is None:  # a field is not a whole number of cells: each point's field from its own coordinates
            fx = np.floor(east / np.float32(self.field_m)).astype(np.int32)
            fy = np.floor(north / np.float32(self.field_m)).astype(np.int32)
            return self.cell_colour(ix, iy, fx, fy)
        w = TABLE_HALF_CELLS
        jx, jy = ix + w, iy + w
        inside = (jx >= 0) & (jx < 2 * w) & (jy >= 0) & (jy < 2 * w)
        flat = jx * (2 * w) + jy  # np.take on the flat table: several times faster than table[jx, jy]
        if inside.all():
            return np.take(table, flat, axis=0)
        rgb = np.empty((*ix.shape, 3), dtype=np.float32)
        rgb[inside] = np.take(table, flat[inside], axis=0)
        out = ~inside
        rgb[out] = self.cell_colour(ix[out], iy[out])
        return rgb

    def cell_colour(self, ix: NDArray[np.int32], iy: NDArray[np.int32], fx: NDArray[np.int32] | None = None,
                    fy: NDArray[np.int32] | None = None) -> NDArray[np.float32]:
        """RGB float32 (..., 3) of the cells (ix, iy) in the fields (fx, fy) (by default the fields the cells lie
        in, a field being a whole number of cells): the texture's definition."""
        if fx is None or fy is None:
            per_field = round(self.field_m / self.cell_m)
            fx, fy = np.floor_divide(ix, per_field), np.floor_divide(iy, per_field)
        checker = ((ix + iy) & 1).astype(np.float32)
        cell_noise = (_hash2(ix, iy, self.seed) - np.float32(0.5)) * np.float32(self.noise)
        tint = _hash2(fx, fy, self.seed + 1)
        soil = (1.10, 0.92, 0.90)  # fields shade from green to brownish
        rgb = np.empty((*checker.shape, 3), dtype=np.float32)
        for c in range(3):
            dark = np.float32(self.dark[c])
            span = np.float32(self.light[c] - self.dark[c])
            shade = np.float32(1.0) + tint * np.float32(soil[c] - 1.0)
            rgb[..., c] = (dark + checker * span) * shade + cell_noise
        return np.clip(rgb, 0.0, 255.0, out=rgb)

    @cached_property
    def _table(self) -> NDArray[np.float32] | None:
        """Every cell's colour within ``TABLE_HALF_CELLS``, (ix + half) * 2 * half + iy + half → RGB; None when a field
        is not a whole number of cells (then a cell's field is not its own: computed per pixel)."""
        if not math.isclose(self.field_m / self.cell_m, round(self.field_m / self.cell_m)):
            return None
        w = TABLE_HALF_CELLS
        ix, iy = np.meshgrid(np.arange(-w, w, dtype=np.int32), np.arange(-w, w, dtype=np.int32), indexing="ij")
        return self.cell_colour(ix, iy).reshape(-1, 3)


class Target(Protocol):
    """A ground target: a disc of ``radius_m`` in ``colour`` whose centre follows ``position(t)``."""

    radius_m: float
    colour: RGB

    def position(self, t: float) -> tuple[float, float]:
        """(east, north) metres of the centre at scene time ``t`` seconds."""
        ...


@dataclass(frozen=True)
class LinearTarget:
    """Moves in a straight line at constant velocity (zero velocity = static)."""

    start: tuple[float, float]
    velocity: tuple[float, float] = (0.0, 0.0)
    radius_m: float = 1.5
    colour: RGB = (255, 20, 20)

    def position(self, t: float) -> tuple[float, float]:
        return self.start[0] + self.velocity[0] * t, self.start[1] + self.velocity[1] * t


@dataclass(frozen=True)
class CircularTarget:
    """Circles ``centre`` at ``orbit_m`` radius, counter-clockwise seen from above, one lap per ``period_s``."""

    centre: tuple[float, float]
    orbit_m: float
    period_s: float
    phase_deg: float = 0.0
    radius_m: float = 1.5
    colour: RGB = (255, 20, 20)

    def position(self, t: float) -> tuple[float, float]:
        a = math.radians(self.phase_deg) + 2.0 * math.pi * t / self.period_s
        return self.centre[0] + self.orbit_m * math.cos(a), self.centre[1] + self.orbit_m * math.sin(a)
