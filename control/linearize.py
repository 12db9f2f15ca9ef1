"""Linearisation of a casadi model ``ẋ = f(x, u)`` and its zero-order-hold discretisation.

casadi differentiates the model symbolically (``jacobian``), so the Jacobians are exact at the operating
point; along a path each point gets its own ``(A, B)`` (seed 002: "linearización del sistema en torno a una
trayectoria y un set point").
"""

from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import expm

Array = NDArray[np.float64]


def jacobians(f: ca.Function) -> ca.Function:
    """A casadi function ``(x, u) → (A, B)`` with ``A = ∂f/∂x``, ``B = ∂f/∂u``; ``f`` takes ``(x, u)``."""
    x = ca.SX.sym("x", f.size1_in(0))
    u = ca.SX.sym("u", f.size1_in(1))
    dx = f(x, u)
    return ca.Function("jac_" + f.name(), [x, u], [ca.jacobian(dx, x), ca.jacobian(dx, u)], ["x", "u"], ["A", "B"])


def linearize(f: ca.Function, x0: ArrayLike, u0: ArrayLike) -> tuple[Array, Array]:
    """Continuous ``(A, B)`` of ``f`` at the operating point ``(x0, u0)``."""
    a, b = jacobians(f)(np.asarray(x0, dtype=float), np.asarray(u0, dtype=float))
    return np.array(a, dtype=float), np.array(b, dtype=float)


def linearize_along(f: ca.Function, points: Sequence[tuple[ArrayLike, ArrayLike]]) -> list[tuple[Array, Array]]:
    """``(A, B)`` at each operating point of a path (one casadi Jacobian function, evaluated per point)."""
    jac = jacobians(f)
    out = []
    for x0, u0 in points:
        a, b = jac(np.asarray(x0, dtype=float), np.asarray(u0, dtype=float))
        out.append((np.array(a, dtype=float), np.array(b, dtype=float)))
    return out


def discretize(a: ArrayLike, b: ArrayLike, ts: float) -> tuple[Array, Array]:
    """Zero-order hold: ``Ad = e^{A·Ts}``, ``Bd = ∫₀^Ts e^{Aτ} dτ · B`` (one matrix exponential)."""
    if not ts > 0:
        raise ValueError(f"sampling period must be positive, got {ts!r}")
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    n, m = a.shape[0], b.shape[1]
    block = np.zeros((n + m, n + m))
    block[:n, :n] = a
    block[:n, n:] = b
    e = expm(block * ts)
    return e[:n, :n], e[:n, n:]
