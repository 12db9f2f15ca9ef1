"""WGS84 conversions and the rotation conventions georeferencing relies on."""

from __future__ import annotations

import numpy as np
import pytest

from bbcs.geodesy import WGS84_A, WGS84_F
from modules.lidar_logger.geodesy import (
    ecef_from_enu,
    ecef_from_nwu,
    ecef_to_lla,
    euler_to_matrix,
    lla_to_ecef,
    matrix_to_euler,
)


def test_known_ecef_points() -> None:
    assert lla_to_ecef(np.array([0.0, 0.0, 0.0])) == pytest.approx([WGS84_A, 0, 0])
    assert lla_to_ecef(np.array([90.0, 0.0, 0.0])) == pytest.approx([0, 0, WGS84_A * (1 - WGS84_F)], abs=1e-6)
    assert lla_to_ecef(np.array([0.0, 90.0, 100.0])) == pytest.approx([0, WGS84_A + 100, 0], abs=1e-6)


def test_lla_ecef_roundtrip() -> None:
    rng = np.random.default_rng(0)
    lla = np.column_stack(
        (rng.uniform(-89.9, 89.9, 1000), rng.uniform(-180, 180, 1000), rng.uniform(-500, 9000, 1000))
    )
    back = ecef_to_lla(lla_to_ecef(lla))
    assert np.abs(back[:, :2] - lla[:, :2]).max() < 1e-10
    assert np.abs(back[:, 2] - lla[:, 2]).max() < 1e-6


def test_local_frames_are_rotations_with_the_right_axes() -> None:
    r = ecef_from_enu(0.0, 0.0)
    assert r[:, 0] == pytest.approx([0, 1, 0]) and r[:, 1] == pytest.approx([0, 0, 1])
    assert r[:, 2] == pytest.approx([1, 0, 0])
    nwu = ecef_from_nwu(0.0, 0.0)
    assert nwu[:, 1] == pytest.approx([0, -1, 0]), "west is minus east"
    m = ecef_from_enu(37.4, -6.0)
    assert m.T @ m == pytest.approx(np.eye(3)) and np.linalg.det(m) == pytest.approx(1.0)


def test_euler_convention_of_the_mti_g() -> None:
    x, y = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    assert euler_to_matrix(np.array([0, 0, 90.0])) @ x == pytest.approx(
        [0, 1, 0], abs=1e-12
    )  # yaw: north to west
    assert euler_to_matrix(np.array([0, 90.0, 0])) @ x == pytest.approx(
        [0, 0, -1], abs=1e-12
    )  # pitch: nose down
    assert euler_to_matrix(np.array([90.0, 0, 0])) @ y == pytest.approx(
        [0, 0, 1], abs=1e-12
    )  # roll: left wing up
    e = np.array([10.0, -20.0, 170.0])
    expect = (
        euler_to_matrix(np.array([0, 0, 170.0]))
        @ euler_to_matrix(np.array([0, -20.0, 0]))
        @ euler_to_matrix(np.array([10.0, 0, 0]))
    )
    assert euler_to_matrix(e) == pytest.approx(expect)


def test_euler_matrix_roundtrip() -> None:
    rng = np.random.default_rng(1)
    e = np.column_stack((rng.uniform(-180, 180, 500), rng.uniform(-89, 89, 500), rng.uniform(-180, 180, 500)))
    assert np.abs(matrix_to_euler(euler_to_matrix(e)) - e).max() < 1e-9
