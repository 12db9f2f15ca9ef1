"""Seed 002's control laws as pure functions (numpy arrays or floats in, same out).

Proportional (eq. 1.4) ``ω_prop = K_prop (sp − x)``; integral with the three thresholds of the seed's
pseudocode; ``ω_int = K_int x_int`` (eq. 1.5); total ``ω = sp_ω + ω_prop + ω_int`` (eq. 1.6); output saturation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


@dataclass(frozen=True)
class AntiWindup:
    """The integrator's thresholds, per integrated variable (scalars or arrays of the state's shape).

    ``th_dist``: no integration while ``|err| > th_dist`` (the proportional action must solve that first);
    ``th_max``: each step integrates at most ``th_max · Ts`` (the integral cannot grow too fast);
    ``accum_low``/``accum_high``: the accumulator saturates there (seed: ``± th_accum``).
    """

    th_dist: ArrayLike = np.inf
    th_max: ArrayLike = np.inf
    accum_high: ArrayLike = np.inf
    accum_low: ArrayLike | None = None  # None: −accum_high (the seed's symmetric ± th_accum)

    def low(self) -> ArrayLike:
        return -np.asarray(self.accum_high, dtype=float) if self.accum_low is None else self.accum_low


def proportional(k_prop: ArrayLike, sp: ArrayLike, x: ArrayLike) -> Array:
    """Seed eq. 1.4: ``K_prop (sp − x)``; ``k_prop`` a matrix (or scalar gain)."""
    err = np.asarray(sp, dtype=float) - np.asarray(x, dtype=float)
    k = np.asarray(k_prop, dtype=float)
    return k @ err if k.ndim == 2 else k * err


def integrate(previous: ArrayLike, err: ArrayLike, ts: float, aw: AntiWindup) -> Array:
    """One step of the seed's integral: keep ``previous`` where ``|err| > th_dist``; elsewhere add the error
    times ``ts`` clamped to ``± th_max·ts``, then saturate the accumulator to ``[accum_low, accum_high]``."""
    if not ts > 0:
        raise ValueError(f"sampling period must be positive, got {ts!r}")
    prev = np.asarray(previous, dtype=float)
    e = np.asarray(err, dtype=float)
    th_max = np.asarray(aw.th_max, dtype=float) * ts
    step = np.clip(e * ts, -th_max, th_max)
    acc = np.clip(prev + step, aw.low(), aw.accum_high)
    return np.where(np.abs(e) > np.asarray(aw.th_dist, dtype=float), prev, acc)


def integrate_scalar(previous: float, err: float, ts: float, th_dist: float, th_max: float, low: float,
                     high: float) -> float:
    """:func:`integrate` for one variable in plain floats (a DSP loop calls it every few milliseconds)."""
    if not ts > 0:
        raise ValueError(f"sampling period must be positive, got {ts!r}")
    if abs(err) > th_dist:
        return previous
    step = min(max(err * ts, -th_max * ts), th_max * ts)
    return min(max(previous + step, low), high)


def integral_action(k_int: ArrayLike, x_int: ArrayLike) -> Array:
    """Seed eq. 1.5: ``ω_int = K_int x_int``."""
    k = np.asarray(k_int, dtype=float)
    xi = np.asarray(x_int, dtype=float)
    return k @ xi if k.ndim == 2 else k * xi


def total_action(sp_omega: ArrayLike, omega_prop: ArrayLike, omega_int: ArrayLike) -> Array:
    """Seed eq. 1.6: ``ω = sp_ω + ω_prop + ω_int``."""
    return np.asarray(sp_omega, dtype=float) + np.asarray(omega_prop, dtype=float) + np.asarray(omega_int, float)


def saturate(value: ArrayLike, low: ArrayLike, high: ArrayLike) -> Array:
    """Output saturation; ``low > high`` is a configuration error, not something to clip silently."""
    if np.any(np.asarray(low) > np.asarray(high)):
        raise ValueError(f"saturation low {low!r} above high {high!r}")
    return np.clip(np.asarray(value, dtype=float), low, high)
