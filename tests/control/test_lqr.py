"""casadi linearisation and the discrete LQR, checked against independent solutions."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from control.linearize import discretize, linearize, linearize_along
from control.lqr import dlqr, solve_dare


def pendulum() -> ca.Function:
    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    return ca.Function("pend", [x, u], [ca.vertcat(x[1], -9.81 * ca.sin(x[0]) - 0.3 * x[1] + 2.0 * u[0] * x[0])])


def test_jacobians_match_hand_derivatives() -> None:
    a, b = linearize(pendulum(), [0.5, 1.0], [0.25])
    assert a == pytest.approx(np.array([[0.0, 1.0], [-9.81 * np.cos(0.5) + 2.0 * 0.25, -0.3]]))
    assert b == pytest.approx(np.array([[0.0], [2.0 * 0.5]]))


def test_linearize_along_points() -> None:
    pts = [([0.0, 0.0], [0.0]), ([np.pi, 0.0], [0.0])]
    (a0, _), (a1, _) = linearize_along(pendulum(), pts)
    assert a0[1, 0] == pytest.approx(-9.81) and a1[1, 0] == pytest.approx(9.81)


def test_discretize_double_integrator() -> None:
    ad, bd = discretize([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], 0.1)
    assert ad == pytest.approx(np.array([[1.0, 0.1], [0.0, 1.0]]))
    assert bd == pytest.approx(np.array([[0.005], [0.1]]))


@pytest.mark.parametrize("seed", range(5))
def test_dare_matches_scipy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, m = 4, 2
    a = rng.normal(size=(n, n))  # usually unstable: a real test of the stabilising solution
    b = rng.normal(size=(n, m))
    q = np.diag(rng.uniform(0.5, 2.0, n))
    r = np.diag(rng.uniform(0.5, 2.0, m))
    ours = solve_dare(a, b, q, r)
    ref = solve_discrete_are(a, b, q, r)
    assert ours == pytest.approx(ref, rel=1e-8, abs=1e-8)
    k, _ = dlqr(a, b, q, r)
    assert np.max(np.abs(np.linalg.eigvals(a - b @ k))) < 1.0


def test_dare_on_a_discretised_linearisation() -> None:
    a, b = linearize(pendulum(), [np.pi, 0.0], [0.0])  # upright: unstable
    ad, bd = discretize(a, b + np.array([[0.0], [1.0]]), 0.05)
    k, p = dlqr(ad, bd, np.eye(2), np.array([[0.1]]))
    assert p == pytest.approx(solve_discrete_are(ad, bd, np.eye(2), np.array([[0.1]])), rel=1e-8)
    assert np.max(np.abs(np.linalg.eigvals(ad - bd @ k))) < 1.0


def test_uncontrollable_unstable_system_is_refused() -> None:
    with pytest.raises((ValueError, np.linalg.LinAlgError)):
        solve_dare(np.diag([2.0, 0.5]), np.array([[0.0], [1.0]]), np.eye(2), np.eye(1))
