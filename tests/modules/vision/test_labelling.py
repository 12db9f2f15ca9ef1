"""The vectorised labelling must agree with a plain flood fill."""

from collections import deque

import numpy as np
import pytest

from modules.vision.labelling import find_runs, label_image, label_runs


def flood_fill_partition(mask, connectivity):
    """Reference: set of frozensets of pixel coordinates, one per component (BFS)."""
    h, w = mask.shape
    seen = np.zeros_like(mask, dtype=bool)
    if connectivity == 8:
        steps = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]
    else:
        steps = [(-1, 0), (1, 0), (0, -1), (0, 1)]
    parts = set()
    for y, x in zip(*np.nonzero(mask), strict=True):
        if seen[y, x]:
            continue
        comp, queue = [], deque([(y, x)])
        seen[y, x] = True
        while queue:
            cy, cx = queue.popleft()
            comp.append((cy, cx))
            for dy, dx in steps:
                ny, nx = cy + dy, cx + dx
                if 0 <= ny < h and 0 <= nx < w and mask[ny, nx] and not seen[ny, nx]:
                    seen[ny, nx] = True
                    queue.append((ny, nx))
        parts.add(frozenset(comp))
    return parts


def partition_of(labels, count):
    parts = set()
    for lab in range(1, count + 1):
        ys, xs = np.nonzero(labels == lab)
        parts.add(frozenset(zip(ys.tolist(), xs.tolist(), strict=True)))
    return parts


@pytest.mark.parametrize("connectivity", [4, 8])
@pytest.mark.parametrize("density", [0.05, 0.3, 0.5, 0.6, 0.8])
def test_random_masks_match_flood_fill(connectivity, density):
    rng = np.random.default_rng(int(density * 100) + connectivity)
    for shape in [(1, 1), (1, 40), (40, 1), (23, 37), (64, 64)]:
        mask = rng.random(shape) < density
        labels, count = label_image(mask, connectivity)
        expected = flood_fill_partition(mask, connectivity)
        assert count == len(expected)
        assert partition_of(labels, count) == expected


def test_diagonal_touch_joins_only_with_8_connectivity():
    mask = np.array([[1, 0], [0, 1]], dtype=bool)
    assert label_runs(mask, 8).count == 1
    assert label_runs(mask, 4).count == 2


def spiral(n):
    """A one-pixel square spiral path, walls two pixels apart (one component that winds inward)."""
    mask = np.zeros((n, n), dtype=bool)
    mask[0, 0] = True
    y, x, length, turn = 0, 0, n - 1, 0
    while length > 0:
        dy, dx = [(0, 1), (1, 0), (0, -1), (-1, 0)][turn % 4]
        for _ in range(length):
            y, x = y + dy, x + dx
            mask[y, x] = True
        turn += 1
        if turn >= 3 and turn % 2 == 1:
            length -= 2
    return mask


@pytest.mark.parametrize("connectivity", [4, 8])
def test_spiral_needing_many_merges_is_one_component(connectivity):
    mask = spiral(61)
    labels, count = label_image(mask, connectivity)
    assert count == 1
    assert (labels > 0).sum() == mask.sum()


def test_comb_joined_at_the_bottom_is_one_component():
    mask = np.zeros((30, 61), dtype=bool)
    mask[:, ::2] = True
    mask[-1, :] = True
    assert label_runs(mask, 4).count == 1
    mask[-1, :] = False
    assert label_runs(mask, 4).count == 31


def test_runs_cover_edges_and_empty_or_full_masks():
    mask = np.zeros((3, 5), dtype=bool)
    row, start, end = find_runs(mask)
    assert row.size == 0
    assert label_runs(mask).count == 0
    mask[:] = True
    row, start, end = find_runs(mask)
    assert row.tolist() == [0, 1, 2] and start.tolist() == [0, 0, 0] and end.tolist() == [5, 5, 5]
    assert label_runs(mask).count == 1
    mask = np.array([[1, 0, 1, 1, 0, 1]], dtype=bool)
    row, start, end = find_runs(mask)
    assert list(zip(start.tolist(), end.tolist(), strict=True)) == [(0, 1), (2, 4), (5, 6)]


def test_bad_arguments():
    with pytest.raises(ValueError):
        label_runs(np.zeros((2, 2), dtype=bool), connectivity=6)
    with pytest.raises(ValueError):
        find_runs(np.zeros(4, dtype=bool))
