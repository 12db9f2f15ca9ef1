"""The uQuad's control law (seed 002 §1.2.5): ``ω = sp_ω + K_prop (sp − x) + K_int x_int``.

Two modes:
- ``hover``: ``K_prop``/``K_int`` read from files (made at yaw 0); position and velocity errors are turned into
  the yaw frame first, so the same matrices hold at any heading;
- ``setpoint``: gains by LQR on the model linearised at the set point (its yaw and velocity), recomputed when
  the path planner flags a new target; errors in the world frame.

The integral runs on (x, y, z, θ) errors with the seed's three anti-windup thresholds (``control.laws``); the
sampling period is the one the caller measured. Output clipped to [MOTOR_MIN, MOTOR_MAX].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from control.laws import AntiWindup, integral_action, integrate, proportional, saturate, total_action
from modules.uquad import model
from modules.uquad.config import LqrConf
from modules.uquad.gains import INTEGRATED, lqr_gains


def wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


@dataclass
class SetPoint:
    """What the path planner asks for: a state (12, model order) and the motors' feed-forward speed."""

    state: np.ndarray
    sp_omega: np.ndarray
    new_target: bool = False


class Controller:
    def __init__(self, params: model.QuadParams, k_prop: np.ndarray, k_int: np.ndarray, anti_windup: AntiWindup,
                 lqr: LqrConf, min_speed: float, max_speed: float, max_pos_err: float = 1.5,
                 mode: str = "hover") -> None:
        if k_prop.shape != (4, 12) or k_int.shape != (4, 4):
            raise ValueError(f"K_prop must be 4×12 and K_int 4×4, got {k_prop.shape} and {k_int.shape}")
        if mode not in ("hover", "setpoint"):
            raise ValueError(f"controller mode must be 'hover' or 'setpoint', not {mode!r}")
        if mode == "setpoint":  # casadi and scipy now, at start, not in the flight loop at the first new target
            import control.linearize  # noqa: F401
        self.params = params
        self.k_prop_hover = k_prop
        self.k_int_hover = k_int
        self.aw = anti_windup
        self.lqr = lqr
        self.min_speed = min_speed
        self.max_speed = max_speed
        self.max_pos_err = max_pos_err
        self.mode = mode
        self.x_int = np.zeros(len(INTEGRATED))
        self._gains: tuple[np.ndarray, np.ndarray] | None = None
        self.gain_updates = 0

    def reset(self) -> None:
        self.x_int[:] = 0.0

    def errors(self, sp: np.ndarray, x: np.ndarray) -> np.ndarray:
        """``sp − x`` with θ wrapped, the horizontal position error clipped, in the frame the gains expect."""
        err = np.asarray(sp, dtype=float) - np.asarray(x, dtype=float)
        err[model.ITHETA] = wrap(err[model.ITHETA])
        horiz = err[model.IX:model.IY + 1]
        norm = float(np.hypot(*horiz))
        if norm > self.max_pos_err:
            err[model.IX:model.IY + 1] = horiz * (self.max_pos_err / norm)
        if self.mode == "hover":
            c, s = math.cos(x[model.ITHETA]), math.sin(x[model.ITHETA])
            rot = np.array([[c, s], [-s, c]])  # world → yaw frame
            err[model.IX:model.IY + 1] = rot @ err[model.IX:model.IY + 1]
            err[model.IVX:model.IVY + 1] = rot @ err[model.IVX:model.IVY + 1]
        return err

    def gains(self, sp: SetPoint, ts: float) -> tuple[np.ndarray, np.ndarray]:
        if self.mode == "hover":
            return self.k_prop_hover, self.k_int_hover
        if self._gains is None or sp.new_target:
            self._gains = lqr_gains(self.params, self.lqr, ts, theta=float(sp.state[model.ITHETA]),
                                    velocity=tuple(float(v) for v in sp.state[model.IVX:model.IVZ + 1]))
            self.gain_updates += 1
        return self._gains

    def step(self, x: np.ndarray, sp: SetPoint, ts: float) -> np.ndarray:
        """Motor speeds for the estimated state ``x`` (12, model order) and measured period ``ts``."""
        k_prop, k_int = self.gains(sp, ts)
        err = self.errors(sp.state, x)
        omega_prop = proportional(k_prop, err, np.zeros_like(err))
        self.x_int = integrate(self.x_int, err[INTEGRATED], ts, self.aw)
        omega_int = integral_action(k_int, self.x_int)
        return saturate(total_action(sp.sp_omega, omega_prop, omega_int), self.min_speed, self.max_speed)
