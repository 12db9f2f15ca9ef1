"""The quadrotor's rigid-body model, written once for numpy (the simulator) and casadi (linearisation, LQR).

State (12, the seed's order): position x y z (m, world frame x east, y north, z up), Euler angles ψ φ θ (rad:
roll about x, pitch about y, yaw about z; R = Rz(θ)·Ry(φ)·Rx(ψ) maps body to world), velocity vx vy vz (m/s,
world frame), body rates p q r (rad/s). Input: the four motors' angular speeds (rad/s), '+' layout: motor 0
front (+x body), 1 left (+y), 2 back, 3 right; 0 and 2 spin one way, 1 and 3 the other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec
import numpy as np

from bbcs import load_conf

if TYPE_CHECKING:
    import casadi as ca

N_STATES = 12
N_MOTORS = 4
IX, IY, IZ, IPSI, IPHI, ITHETA, IVX, IVY, IVZ, IP, IQ, IR = range(12)


class QuadParams(msgspec.Struct, frozen=True, kw_only=True):
    """Physical parameters (group ``QUAD: model`` of the robot .conf)."""

    mass: float = 1.5
    """kg"""
    arm: float = 0.29
    """m, motor axis to centre"""
    ixx: float = 0.0154
    iyy: float = 0.0154
    izz: float = 0.0282
    """kg·m²"""
    k_thrust: float = 1.5e-5
    """N per (rad/s)²"""
    k_torque: float = 2.5e-7
    """N·m per (rad/s)²"""
    drag: float = 0.25
    """linear drag, N per m/s"""
    motor_tau: float = 0.04
    """s, first-order motor response (simulator)"""
    g: float = 9.81

    @property
    def hover_speed(self) -> float:
        return math.sqrt(self.mass * self.g / (N_MOTORS * self.k_thrust))


def load_params(conf_path: str | Path) -> QuadParams:
    doc = load_conf(conf_path)
    return doc.group("QUAD", "model").to_struct(QuadParams)


def rates(x: Any, w: Any, p: QuadParams, lib: Any = np) -> list[Any]:
    """ẋ for state ``x`` and motor speeds ``w``; ``lib`` is numpy or casadi (the same expressions for both)."""
    sin, cos, tan = lib.sin, lib.cos, lib.tan
    psi, phi, theta = x[IPSI], x[IPHI], x[ITHETA]
    vx, vy, vz, pr, qr, rr = x[IVX], x[IVY], x[IVZ], x[IP], x[IQ], x[IR]
    f = [p.k_thrust * w[i] * w[i] for i in range(4)]
    thrust = f[0] + f[1] + f[2] + f[3]
    tau_x = p.arm * (f[1] - f[3])
    tau_y = p.arm * (f[2] - f[0])
    tau_z = p.k_torque / p.k_thrust * (f[0] - f[1] + f[2] - f[3])
    cps, sps, cph, sph, cth, sth = cos(psi), sin(psi), cos(phi), sin(phi), cos(theta), sin(theta)
    # third column of R = Rz(θ)·Ry(φ)·Rx(ψ): the thrust direction in the world frame
    ux = cth * sph * cps + sth * sps
    uy = sth * sph * cps - cth * sps
    uz = cph * cps
    ax = thrust / p.mass * ux - p.drag / p.mass * vx
    ay = thrust / p.mass * uy - p.drag / p.mass * vy
    az = thrust / p.mass * uz - p.drag / p.mass * vz - p.g
    dpsi = pr + (qr * sps + rr * cps) * tan(phi)
    dphi = qr * cps - rr * sps
    dtheta = (qr * sps + rr * cps) / cph
    dp = (tau_x - (p.izz - p.iyy) * qr * rr) / p.ixx
    dq = (tau_y - (p.ixx - p.izz) * pr * rr) / p.iyy
    dr = (tau_z - (p.iyy - p.ixx) * pr * qr) / p.izz
    return [vx, vy, vz, dpsi, dphi, dtheta, ax, ay, az, dp, dq, dr]


def casadi_model(p: QuadParams) -> ca.Function:
    """``f(x, u) → ẋ`` as a casadi Function, for :func:`control.linearize.linearize`."""
    import casadi as ca  # here, not at import: the flight loop starts without casadi (hover gains from files)

    x = ca.SX.sym("x", N_STATES)
    u = ca.SX.sym("u", N_MOTORS)
    return ca.Function("uquad", [x, u], [ca.vertcat(*rates(x, u, p, ca))], ["x", "u"], ["xdot"])


def rotation(psi: float, phi: float, theta: float) -> np.ndarray:
    """Body → world: Rz(θ)·Ry(φ)·Rx(ψ)."""
    cps, sps, cph, sph, cth, sth = (math.cos(psi), math.sin(psi), math.cos(phi), math.sin(phi), math.cos(theta),
                                    math.sin(theta))
    rz = np.array([[cth, -sth, 0], [sth, cth, 0], [0, 0, 1]])
    ry = np.array([[cph, 0, sph], [0, 1, 0], [-sph, 0, cph]])
    rx = np.array([[1, 0, 0], [0, cps, -sps], [0, sps, cps]])
    return rz @ ry @ rx


def rotation_and_derivatives(psi: float, phi: float, theta: float) -> tuple[np.ndarray, ...]:
    """R = Rz(θ)·Ry(φ)·Rx(ψ) and its partial derivatives ∂R/∂ψ, ∂R/∂φ, ∂R/∂θ (for the Kalman filter's
    Jacobian), written out element by element."""
    cps, sps, cph, sph, cth, sth = (math.cos(psi), math.sin(psi), math.cos(phi), math.sin(phi), math.cos(theta),
                                    math.sin(theta))
    r = np.array([
        [cth * cph, cth * sph * sps - sth * cps, cth * sph * cps + sth * sps],
        [sth * cph, sth * sph * sps + cth * cps, sth * sph * cps - cth * sps],
        [-sph, cph * sps, cph * cps],
    ])
    d_psi = np.array([
        [0.0, cth * sph * cps + sth * sps, -cth * sph * sps + sth * cps],
        [0.0, sth * sph * cps - cth * sps, -sth * sph * sps - cth * cps],
        [0.0, cph * cps, -cph * sps],
    ])
    d_phi = np.array([
        [-cth * sph, cth * cph * sps, cth * cph * cps],
        [-sth * sph, sth * cph * sps, sth * cph * cps],
        [-cph, -sph * sps, -sph * cps],
    ])
    d_theta = np.array([
        [-sth * cph, -sth * sph * sps - cth * cps, -sth * sph * cps + cth * sps],
        [cth * cph, cth * sph * sps - sth * cps, cth * sph * cps + sth * sps],
        [0.0, 0.0, 0.0],
    ])
    return r, d_psi, d_phi, d_theta


@dataclass(frozen=True)
class Hover:
    x0: np.ndarray
    u0: np.ndarray


def hover_point(p: QuadParams, theta: float = 0.0) -> Hover:
    x0 = np.zeros(N_STATES)
    x0[ITHETA] = theta
    return Hover(x0=x0, u0=np.full(N_MOTORS, p.hover_speed))
