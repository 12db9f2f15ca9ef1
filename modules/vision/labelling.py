"""Connected components of a binary mask, vectorised: run lengths + union-find over overlapping runs.

1. Each row of the mask becomes horizontal runs (row, start, end exclusive), found with one ``np.diff``.
2. Runs of consecutive rows that touch are linked. Runs are ordered row-major and, within a row, both their
   starts and ends increase, so the runs of the row above that touch a run form a contiguous index range
   found by two ``searchsorted`` calls on (row, column) keys.
3. Linked runs are merged by label propagation to the minimum index with pointer jumping (every label points
   to a smaller-or-equal index, so no cycles; each round hooks every root that still has a differing
   neighbour). Rounds are few because raster-ordered runs already carry nearly sorted labels.

Cost is one pass over the image plus work proportional to the number of runs, not pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

IntArray = NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class Runs:
    """Horizontal runs of set pixels, row-major; ``label`` is the component index (0..count-1)."""

    row: IntArray
    start: IntArray
    end: IntArray
    label: IntArray
    count: int

    @property
    def length(self) -> IntArray:
        return self.end - self.start


def find_runs(mask: NDArray[np.bool_]) -> tuple[IntArray, IntArray, IntArray]:
    """(row, start, end-exclusive) of every run of True pixels, row-major order."""
    if mask.ndim != 2:
        raise ValueError(f"mask must be 2-D, not {mask.shape}")
    height, width = mask.shape
    padded = np.zeros((height, width + 2), dtype=np.int8)
    padded[:, 1:-1] = mask
    steps = np.diff(padded, axis=1).ravel()  # (height, width + 1): +1 at a run start, -1 one past its end
    where = np.flatnonzero(steps)
    kind = steps[where]
    starts = where[kind == 1]
    ends = where[kind == -1]
    row = starts // (width + 1)
    return row, starts - row * (width + 1), ends - row * (width + 1)


def _touching_pairs(
    row: IntArray, start: IntArray, end: IntArray, width: int, connectivity: int
) -> tuple[IntArray, IntArray]:
    """Index pairs (upper, lower) of runs in consecutive rows that touch."""
    span = width + 2
    key_start = row * span + start
    key_end = row * span + end
    above = (row - 1) * span
    if connectivity == 8:  # diagonal contact counts: upper.end >= lower.start and upper.start <= lower.end
        lo = np.searchsorted(key_end, above + start, side="left")
        hi = np.searchsorted(key_start, above + end, side="right")
    else:  # edge contact only: upper.end > lower.start and upper.start < lower.end
        lo = np.searchsorted(key_end, above + start, side="right")
        hi = np.searchsorted(key_start, above + end, side="left")
    counts = np.maximum(hi - lo, 0)
    total = int(counts.sum())
    lower = np.repeat(np.arange(row.size), counts)
    first = np.repeat(lo, counts)
    offsets = np.repeat(np.cumsum(counts) - counts, counts)
    upper = first + (np.arange(total) - offsets)
    return upper, lower


def _merge(n: int, a: IntArray, b: IntArray) -> IntArray:
    """Component representative (minimum run index) for each of n runs linked by edges a-b."""
    parent = np.arange(n)
    while a.size:
        ra, rb = parent[a], parent[b]
        differ = ra != rb
        if not differ.any():
            break
        ra, rb = ra[differ], rb[differ]
        low = np.minimum(ra, rb)
        np.minimum.at(parent, ra, low)
        np.minimum.at(parent, rb, low)
        while True:  # pointer jumping until every run points at its root
            jumped = parent[parent]
            if np.array_equal(jumped, parent):
                break
            parent = jumped
        a, b = a[differ], b[differ]
    return parent


def label_runs(mask: NDArray[np.bool_], connectivity: int = 8) -> Runs:
    """Label the connected components of ``mask`` (4- or 8-connectivity)."""
    if connectivity not in (4, 8):
        raise ValueError(f"connectivity must be 4 or 8, not {connectivity}")
    row, start, end = find_runs(mask)
    upper, lower = _touching_pairs(row, start, end, mask.shape[1], connectivity)
    roots = _merge(row.size, upper, lower)
    unique_roots, label = np.unique(roots, return_inverse=True)
    return Runs(row=row, start=start, end=end, label=label.astype(np.int64), count=int(unique_roots.size))


def label_image(mask: NDArray[np.bool_], connectivity: int = 8) -> tuple[NDArray[np.int32], int]:
    """Dense label image (0 = background, components 1..count) — for tests and debugging."""
    runs = label_runs(mask, connectivity)
    out = np.zeros(mask.shape, dtype=np.int32)
    for r, s, e, lab in zip(runs.row, runs.start, runs.end, runs.label, strict=True):
        out[r, s:e] = lab + 1
    return out, runs.count
