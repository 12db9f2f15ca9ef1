"""The vectorised point-line formatter writes exactly what ``POINT_FMT % row`` writes, edge cases included."""

from __future__ import annotations

import numpy as np
import pytest

from modules.lidar_logger.textfmt import POINT_FMT, _format_points_slow, format_points


def reference(xyz, width, flags, layer, echo, offset) -> bytes:
    """One ``%`` per line, written independently of the module's own slow path."""
    lines = []
    for i in range(len(xyz)):
        row = (i + 1, *map(float, xyz[i]), width[i] / 100.0, int(flags[i]), int(layer[i]), int(echo[i]),
               int(offset[i]), int(flags[i] == 0), 0)
        lines.append(POINT_FMT % row)
    return "".join(lines).encode("ascii")


def columns(rng: np.random.Generator, n: int, scale: float = 200.0):
    xyz = rng.uniform(-scale, scale, (n, 3))
    width = rng.integers(0, 400, n)
    flags = rng.choice([0, 0, 0, 1, 2, 4, 0x1000, 0x10000 | 1], n)
    layer = rng.integers(0, 4, n)
    echo = rng.integers(0, 3, n)
    offset = rng.integers(0, 30000, n)
    return xyz, width, flags, layer, echo, offset


@pytest.mark.parametrize("seed", range(5))
def test_random_scans_match_the_percent_format(seed: int) -> None:
    cols = columns(np.random.default_rng(seed), 700)
    assert format_points(*cols) == reference(*cols) == _format_points_slow(*cols)


def test_edge_values_match_the_percent_format() -> None:
    xyz = np.array([
        [0.0, -0.0, 1e-12], [-1e-12, -4e-9, 5e-9],          # signed zeros and values that round to zero
        [0.123456785, 1.000000005, -2.500000005],           # half-way cases in the 9th decimal
        [9999.99999999, -9999.999999996, 655.35],           # carries into the integer part
        [123456.7, -0.5, 7.0],
    ])
    width = np.array([0, 5, 99, 100, 65535])
    flags = np.array([0, 0x80000, 1, 0, 4])
    layer = np.array([0, 3, 1, 2, 0])
    echo = np.array([0, 1, 2, 3, 15])
    offset = np.array([0, -7, 12345, 99_999_999, 10])
    assert format_points(xyz, width, flags, layer, echo, offset) == reference(xyz, width, flags, layer, echo,
                                                                              offset)
    assert format_points(xyz[:0], width[:0], flags[:0], layer[:0], echo[:0], offset[:0]) == b""


def test_numbers_too_wide_for_the_fast_path_fall_back_exactly() -> None:
    xyz = np.array([[2e7, 1.0, -3e8]])
    one = np.array([1])
    big = np.array([123_456_789_012])
    assert format_points(xyz, one, one, one, one, big) == reference(xyz, one, one, one, one, big)
