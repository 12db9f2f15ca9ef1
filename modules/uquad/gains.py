"""Control gains by LQR on the linearised model (casadi via :mod:`control`), with integral states on x, y, z, θ.

The seed's hover matrices (``K_prop`` 4×12, ``K_int`` 4×4) are made by this module once and stored as text
files (``python -m modules.uquad.gains --conf bbcs_conf/uquad1.conf``); the set-point mode calls
:func:`lqr_gains` at run time for each new set point. With ``u = u0 + K_prop (sp − x) + K_int x_int`` and
``x_int`` the integral of ``sp − x`` on (x, y, z, θ), the augmented LQR ``u = −[Kx Kz] [x − sp; ∫(x − sp)]``
gives ``K_prop = Kx`` and ``K_int = Kz``.
"""

from __future__ import annotations

import argparse
import sys
from functools import lru_cache

import numpy as np

from control.lqr import dlqr
from modules.uquad import model
from modules.uquad.config import LqrConf, load_config

INTEGRATED = [model.IX, model.IY, model.IZ, model.ITHETA]


def lqr_gains(params: model.QuadParams, weights: LqrConf, ts: float, theta: float = 0.0,
              velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """``(K_prop, K_int)`` for sampling period ``ts``, linearised at hover with yaw ``theta`` (and velocity)."""
    return _cached(params, tuple(weights.q), tuple(weights.q_int), tuple(weights.r), round(ts, 4), round(theta, 3),
                   tuple(round(v, 2) for v in velocity))


@lru_cache(maxsize=64)
def _cached(params: model.QuadParams, q: tuple[float, ...], q_int: tuple[float, ...], r: tuple[float, ...],
            ts: float, theta: float, velocity: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    hover = model.hover_point(params, theta)
    x0 = hover.x0.copy()
    x0[model.IVX:model.IVZ + 1] = velocity
    from control.linearize import discretize, linearize  # casadi and scipy: only when gains are computed

    a, b = linearize(_model(params), x0, hover.u0)
    n, m, k = model.N_STATES, model.N_MOTORS, len(INTEGRATED)
    a_aug = np.zeros((n + k, n + k))
    a_aug[:n, :n] = a
    for row, col in enumerate(INTEGRATED):
        a_aug[n + row, col] = 1.0
    b_aug = np.vstack([b, np.zeros((k, m))])
    ad, bd = discretize(a_aug, b_aug, ts)
    gain, _ = dlqr(ad, bd, np.diag([*q, *q_int]), np.diag(r))
    return gain[:, :n], gain[:, n:]


@lru_cache(maxsize=4)
def _model(params: model.QuadParams):  # noqa: ANN202 - casadi Function
    return model.casadi_model(params)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m modules.uquad.gains", description="write the hover K files")
    ap.add_argument("--conf", required=True)
    ap.add_argument("--ts", type=float, default=None, help="sampling period (default: 10 ms × CONTROL_EVERY)")
    args = ap.parse_args(argv)
    cfg = load_config(args.conf)
    ts = args.ts or 0.01 * cfg.values.CONTROL_EVERY
    k_prop, k_int = lqr_gains(cfg.quad, cfg.lqr, ts)
    head = f"uquad hover gains, LQR at hover (yaw 0), Ts = {ts} s, from {args.conf}"
    np.savetxt(cfg.file(cfg.values.K_PROP_FILE), k_prop, fmt="%.6f",
               header=head + "\nK_prop: rows = motors 0..3, columns = x y z psi phi theta vx vy vz p q r")
    np.savetxt(cfg.file(cfg.values.K_INT_FILE), k_int, fmt="%.6f",
               header=head + "\nK_int: rows = motors 0..3, columns = integrals of x y z theta")
    print(f"wrote {cfg.values.K_PROP_FILE} and {cfg.values.K_INT_FILE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
