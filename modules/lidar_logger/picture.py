"""A terrain model as a picture a person can read: heights on a colour ramp shaded by the relief, the survey
polygon's outline, a scale bar in metres, a north arrow and the ramp's legend (``cromat lidar dtm --picture``).

Drawn with numpy alone (a 5 x 7 pixel font for the labels, written here), so the picture needs nothing beyond the
PNG writer the DTM already uses (rasterio, the ``survey`` extra). The map is north up: the grid's rows run
southwards and its columns eastwards, each cell a square of ``scale`` pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from modules.lidar_logger.dtm import Dtm, hillshade

OUTLINE = (255, 0, 255)
"""The polygon's outline: magenta, a colour the ramp never gives."""
NO_DATA = (215, 215, 215)
BACKGROUND = (255, 255, 255)
INK = (0, 0, 0)
RAMP = ((0.0, (35, 110, 70)), (0.25, (95, 160, 75)), (0.5, (225, 215, 120)), (0.75, (190, 130, 60)),
        (1.0, (120, 70, 45)))
"""Height colour ramp, low to high: green, yellow, brown (hypsometric tints)."""
MARGIN = 24
PANEL = 170
"""Width of the panel right of the map: north arrow and legend."""
FOOTER = 70
"""Height of the band under the map: the scale bar."""

_GLYPHS = {
    "0": ("01110", "10001", "10011", "10101", "11001", "10001", "01110"),
    "1": ("00100", "01100", "00100", "00100", "00100", "00100", "01110"),
    "2": ("01110", "10001", "00001", "00010", "00100", "01000", "11111"),
    "3": ("11110", "00001", "00001", "01110", "00001", "00001", "11110"),
    "4": ("00010", "00110", "01010", "10010", "11111", "00010", "00010"),
    "5": ("11111", "10000", "11110", "00001", "00001", "10001", "01110"),
    "6": ("00110", "01000", "10000", "11110", "10001", "10001", "01110"),
    "7": ("11111", "00001", "00010", "00100", "01000", "01000", "01000"),
    "8": ("01110", "10001", "10001", "01110", "10001", "10001", "01110"),
    "9": ("01110", "10001", "10001", "01111", "00001", "00010", "01100"),
    ".": ("00000", "00000", "00000", "00000", "00000", "01100", "01100"),
    "-": ("00000", "00000", "00000", "11111", "00000", "00000", "00000"),
    "m": ("00000", "00000", "11010", "10101", "10101", "10101", "10101"),
    "N": ("10001", "11001", "10101", "10011", "10001", "10001", "10001"),
    " ": ("00000",) * 7,
}


@dataclass(frozen=True)
class Picture:
    """The RGB image and where its parts were drawn (pixel boxes as (row0, col0, row1, col1), ends excluded)."""

    image: np.ndarray
    """(height, width, 3) uint8."""
    scale: int
    """Pixels per DTM cell."""
    map_box: tuple[int, int, int, int]
    legend_box: tuple[int, int, int, int]
    """The colour bar: its top row is the highest height, its bottom row the lowest."""
    heights: tuple[float, float]
    """(lowest, highest) height of the ramp as its legend writes them, metres."""
    scale_bar_m: float
    scale_bar_box: tuple[int, int, int, int]
    arrow_box: tuple[int, int, int, int]

    def pixel_to_en(self, row: float, col: float, dtm: Dtm) -> tuple[float, float]:
        """East, north (m) of a pixel centre of the map."""
        r0, c0 = self.map_box[:2]
        return (dtm.west + (col + 0.5 - c0) / self.scale * dtm.cell,
                dtm.north - (row + 0.5 - r0) / self.scale * dtm.cell)


def ramp(t: np.ndarray) -> np.ndarray:
    """Colours (..., 3) float of ``t`` in [0, 1] on :data:`RAMP`."""
    stops = np.array([s for s, _ in RAMP])
    colours = np.array([c for _, c in RAMP], dtype=np.float64)
    t = np.clip(t, 0.0, 1.0)
    return np.stack([np.interp(t, stops, colours[:, i]) for i in range(3)], axis=-1)


def nice_length(span_m: float) -> float:
    """The largest 1, 2 or 5 x 10^n not above ``span_m`` (a scale bar's length)."""
    if not span_m > 0:
        return 0.0
    base = 10.0 ** math.floor(math.log10(span_m))
    return max(f * base for f in (1.0, 2.0, 5.0) if f * base <= span_m)


def text(image: np.ndarray, s: str, row: int, col: int, size: int = 2, colour: tuple[int, int, int] = INK) -> int:
    """Draw ``s`` with its top-left corner at (row, col), each font pixel ``size`` pixels; returns its width."""
    x = col
    for ch in s:
        glyph = _GLYPHS.get(ch, _GLYPHS[" "])
        for gy, bits in enumerate(glyph):
            for gx, bit in enumerate(bits):
                if bit == "1":
                    _fill(image, row + gy * size, x + gx * size, row + (gy + 1) * size, x + (gx + 1) * size, colour)
        x += 6 * size
    return x - col


def text_width(s: str, size: int = 2) -> int:
    return 6 * size * len(s)


def _fill(image: np.ndarray, r0: int, c0: int, r1: int, c1: int, colour: tuple[int, int, int]) -> None:
    h, w = image.shape[:2]
    r0, r1 = max(0, r0), min(h, r1)
    c0, c1 = max(0, c0), min(w, c1)
    if r0 < r1 and c0 < c1:
        image[r0:r1, c0:c1] = colour


def _frame(image: np.ndarray, r0: int, c0: int, r1: int, c1: int) -> None:
    _fill(image, r0 - 1, c0 - 1, r0, c1 + 1, INK)
    _fill(image, r1, c0 - 1, r1 + 1, c1 + 1, INK)
    _fill(image, r0 - 1, c0 - 1, r1 + 1, c0, INK)
    _fill(image, r0 - 1, c1, r1 + 1, c1 + 1, INK)


def _line(image: np.ndarray, a: np.ndarray, b: np.ndarray, width: int, colour: tuple[int, int, int]) -> None:
    """A thick segment from pixel ``a`` to ``b`` ((row, col) floats): discs stamped every half pixel."""
    steps = max(1, int(np.ceil(2 * np.hypot(*(b - a)))))
    h, w = image.shape[:2]
    radius = width / 2.0
    off = np.arange(-int(np.ceil(radius)), int(np.ceil(radius)) + 1)
    dr, dc = np.meshgrid(off, off, indexing="ij")
    disc = dr**2 + dc**2 <= radius**2
    dr, dc = dr[disc], dc[disc]
    for t in np.linspace(0.0, 1.0, steps + 1):
        r, c = np.rint(a + t * (b - a)).astype(int)
        rr, cc = r + dr, c + dc
        ok = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        image[rr[ok], cc[ok]] = colour


def draw(dtm: Dtm, polygon: np.ndarray | None = None, *, height_offset: float = 0.0, min_long_side: int = 800,
         shade: np.ndarray | None = None) -> Picture:
    """The picture of ``dtm``; ``polygon`` (K, 2) east, north (m) in the DTM's frame is outlined. The legend's
    heights are ``dtm.z + height_offset`` (the origin's height: the GeoTIFF's heights)."""
    rows, cols = dtm.shape
    scale = max(1, math.ceil(min_long_side / max(rows, cols, 1)))
    mh, mw = rows * scale, cols * scale
    arrow_top = MARGIN + 22
    lr0 = arrow_top + 36 + 30
    lr1 = lr0 + min(max(mh - (lr0 - MARGIN) - 10, 120), 400)
    height = max(MARGIN + mh + FOOTER, lr1 + MARGIN)
    width = MARGIN + mw + PANEL
    image = np.full((height, width, 3), BACKGROUND, dtype=np.uint8)

    z = dtm.z
    has = np.isfinite(z)
    lo, hi = (float(np.nanmin(z)), float(np.nanmax(z))) if has.any() else (0.0, 0.0)
    t = (z - lo) / (hi - lo) if hi > lo else np.full(z.shape, 0.5)
    relief = (hillshade(dtm) if shade is None else shade).astype(np.float64) / 255.0
    colour = ramp(np.where(has, t, 0.0)) * (0.45 + 0.55 * relief)[..., None]
    cells = np.where(has[..., None], np.clip(np.rint(colour), 0, 255), np.array(NO_DATA, dtype=np.float64))
    image[MARGIN:MARGIN + mh, MARGIN:MARGIN + mw] = np.repeat(np.repeat(cells.astype(np.uint8), scale, 0), scale, 1)
    _frame(image, MARGIN, MARGIN, MARGIN + mh, MARGIN + mw)

    if polygon is not None and len(polygon) >= 2:
        poly = np.asarray(polygon, dtype=np.float64)
        px = np.column_stack((MARGIN + (dtm.north - poly[:, 1]) / dtm.cell * scale - 0.5,
                              MARGIN + (poly[:, 0] - dtm.west) / dtm.cell * scale - 0.5))
        for a, b in zip(px, np.roll(px, -1, axis=0), strict=True):
            _line(image, a, b, 3, OUTLINE)

    # north arrow, top of the panel: a black triangle pointing up, N above it
    ac = MARGIN + mw + PANEL // 2
    for i in range(36):
        half = i * 12 // 36
        _fill(image, arrow_top + i, ac - half, arrow_top + i + 1, ac + half + 1, INK)
    text(image, "N", MARGIN, ac - 5, 2)
    arrow_box = (MARGIN, ac - 13, arrow_top + 36, ac + 14)

    # legend: the colour bar, highest at the top, its heights written beside it
    lc0 = MARGIN + mw + 22
    bar = ramp(np.linspace(1.0, 0.0, lr1 - lr0))
    image[lr0:lr1, lc0:lc0 + 24] = np.rint(bar).astype(np.uint8)[:, None, :]
    _frame(image, lr0, lc0, lr1, lc0 + 24)
    for frac, value in ((0.0, hi + height_offset), (0.5, (lo + hi) / 2 + height_offset), (1.0, lo + height_offset)):
        r = int(round(lr0 + frac * (lr1 - lr0 - 1)))
        _fill(image, r, lc0 + 24, r + 1, lc0 + 30, INK)
        text(image, f"{value:.1f} m", r - 7, lc0 + 34, 2)
    legend_box = (lr0, lc0, lr1, lc0 + 24)

    # scale bar under the map: about a third of its width, four segments black and white
    length_m = nice_length(cols * dtm.cell / 3.0)
    length_px = int(round(length_m / dtm.cell * scale))
    br0 = MARGIN + mh + 18
    bc0 = MARGIN
    for i in range(4):
        c0, c1 = bc0 + i * length_px // 4, bc0 + (i + 1) * length_px // 4
        _fill(image, br0, c0, br0 + 10, c1, INK if i % 2 == 0 else BACKGROUND)
    _frame(image, br0, bc0, br0 + 10, bc0 + length_px)
    text(image, "0", br0 + 16, bc0 - 5, 2)
    label = f"{length_m:g} m"
    text(image, label, br0 + 16, bc0 + length_px - text_width(label) // 2, 2)
    return Picture(image=image, scale=scale, map_box=(MARGIN, MARGIN, MARGIN + mh, MARGIN + mw),
                   legend_box=legend_box, heights=(lo + height_offset, hi + height_offset), scale_bar_m=length_m,
                   scale_bar_box=(br0, bc0, br0 + 10, bc0 + length_px), arrow_box=arrow_box)
