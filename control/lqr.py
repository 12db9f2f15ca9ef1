"""Discrete LQR from the discrete algebraic Riccati equation, solved by our own iteration.

``P = Q + Aᵀ P A − Aᵀ P B (R + Bᵀ P B)⁻¹ Bᵀ P A``, ``K = (R + Bᵀ P B)⁻¹ Bᵀ P A``, control ``u = −K x``.
The doubling form (structure-preserving doubling) converges quadratically, so a few dozen iterations reach
machine precision even for slow poles; tests check it against ``scipy.linalg.solve_discrete_are``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def solve_dare(a: ArrayLike, b: ArrayLike, q: ArrayLike, r: ArrayLike, *, tol: float = 1e-12,
               max_iter: int = 200) -> Array:
    """Stabilising solution ``P`` of the DARE by the doubling algorithm; ValueError if it does not converge."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    q = np.asarray(q, dtype=float)
    r = np.asarray(r, dtype=float)
    n = a.shape[0]
    ak = a.copy()
    gk = b @ np.linalg.solve(r, b.T)
    hk = q.copy()
    eye = np.eye(n)
    for _ in range(max_iter):
        with np.errstate(all="ignore"):
            w = np.linalg.solve(eye + gk @ hk, np.hstack([ak, gk]))
            w_a, w_g = w[:, :n], w[:, n:]
            h_next = hk + ak.T @ hk @ w_a
            g_next = gk + ak @ w_g @ ak.T
            a_next = ak @ w_a
        if not np.all(np.isfinite(h_next)):
            break  # diverged: an unstable mode the input cannot reach
        if np.linalg.norm(h_next - hk, 1) <= tol * max(1.0, np.linalg.norm(h_next, 1)):
            return (h_next + h_next.T) / 2.0
        ak, gk, hk = a_next, g_next, h_next
    raise ValueError("discrete Riccati iteration did not converge (is (A, B) stabilisable?)")


def dlqr(a: ArrayLike, b: ArrayLike, q: ArrayLike, r: ArrayLike) -> tuple[Array, Array]:
    """Gain ``K`` (``u = −K x``) and Riccati solution ``P`` of the discrete LQR."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    p = solve_dare(a, b, q, r)
    k = np.linalg.solve(np.asarray(r, dtype=float) + b.T @ p @ b, b.T @ p @ a)
    return k, p
