"""The helicopter, written once in casadi: the DSP simulator integrates it, the onboard follower derives from it.

Rigid body with Euler-angle kinematics, rotor flapping lag on both cyclics, collective lag, thrust along the
tilted rotor axis, linear drag against the air (ground velocity minus wind). Local frame north, east, up;
heading ψ clockwise from north; pitch θ nose up, roll φ right wing down (so nose down accelerates forward and
roll right accelerates to the right). Angles in radians here (the DSP's PIDs work in degrees: see
modules/dsp/sim/vehicle.py).

State ``x`` (15): n, e, h, vn, ve, vu, φ, θ, ψ, p, q, r, flap_lat, flap_lon, collective.
Input ``u`` (4): lateral cyclic, longitudinal cyclic, tail rotor (all −1…1), collective (0…1).
Environment ``w`` (4): wind north, east, up (m/s), rotor speed / nominal rotor speed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # casadi takes ~1 s to import: only the functions that build a model import it
    import casadi as ca

G = 9.80665
NX, NU, NW = 15, 4, 4


@dataclass(frozen=True)
class HeliParams:
    """Airframe constants (a 13 kg class single-rotor helicopter, rounded)."""

    roll_authority: float = 19.0  # rad/s² per unit of lateral flapping
    pitch_authority: float = 17.0  # rad/s² per unit of longitudinal flapping
    yaw_authority: float = 7.85  # rad/s² per unit of tail rotor
    roll_damping: float = 0.5  # 1/s
    pitch_damping: float = 0.5
    yaw_damping: float = 3.3
    flap_tau: float = 0.04  # s, rotor flapping lag (cyclic → disc tilt)
    collective_tau: float = 0.10  # s, collective servo + inflow lag
    hover_collective: float = 0.42  # collective that hovers at nominal rotor speed
    drag_h: float = 0.25  # 1/s, horizontal drag per m/s of airspeed
    drag_v: float = 0.6  # 1/s, vertical drag


def dynamics(par: HeliParams | None = None) -> ca.Function:
    """``f(x, u, w) → ẋ`` as a casadi Function."""
    import casadi as ca

    par = par or HeliParams()
    x = ca.SX.sym("x", NX)
    u = ca.SX.sym("u", NU)
    w = ca.SX.sym("w", NW)
    vn, ve, vu = x[3], x[4], x[5]
    phi, theta, psi = x[6], x[7], x[8]
    p, q, r = x[9], x[10], x[11]
    fa, fe, coll = x[12], x[13], x[14]
    thrust = G * coll / par.hover_collective * w[3] ** 2  # per unit mass
    a_fwd = -thrust * ca.sin(theta) * ca.cos(phi)
    a_right = thrust * ca.sin(phi)
    a_n = a_fwd * ca.cos(psi) - a_right * ca.sin(psi) - par.drag_h * (vn - w[0])
    a_e = a_fwd * ca.sin(psi) + a_right * ca.cos(psi) - par.drag_h * (ve - w[1])
    a_u = thrust * ca.cos(phi) * ca.cos(theta) - G - par.drag_v * (vu - w[2])
    dphi = p + ca.tan(theta) * (q * ca.sin(phi) + r * ca.cos(phi))
    dtheta = q * ca.cos(phi) - r * ca.sin(phi)
    dpsi = (q * ca.sin(phi) + r * ca.cos(phi)) / ca.cos(theta)
    dx = ca.vertcat(
        vn, ve, vu, a_n, a_e, a_u, dphi, dtheta, dpsi,
        par.roll_authority * fa - par.roll_damping * p,
        par.pitch_authority * fe - par.pitch_damping * q,
        par.yaw_authority * u[2] - par.yaw_damping * r,
        (u[0] - fa) / par.flap_tau, (u[1] - fe) / par.flap_tau, (u[3] - coll) / par.collective_tau,
    )
    return ca.Function("heli", [x, u, w], [dx], ["x", "u", "w"], ["dx"])


def rk4_step(par: HeliParams | None = None) -> ca.Function:
    """``F(x, u, w, h) → x(t+h)``: one classical Runge-Kutta step of :func:`dynamics`, inputs held."""
    import casadi as ca

    f = dynamics(par)
    x = ca.SX.sym("x", NX)
    u = ca.SX.sym("u", NU)
    w = ca.SX.sym("w", NW)
    h = ca.SX.sym("h")
    k1 = f(x, u, w)
    k2 = f(x + h / 2 * k1, u, w)
    k3 = f(x + h / 2 * k2, u, w)
    k4 = f(x + h * k3, u, w)
    return ca.Function("heli_rk4", [x, u, w, h], [x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])


@dataclass(frozen=True)
class GuidedParams:
    """The helicopter as the onboard follower sees it: the DSP in bridge mode turns a velocity command into
    velocity through its reference shaping and attitude loops, reduced here to first-order lags.

    The lags follow from :class:`HeliParams` and the DSP's loops: the attitude loop's settling (about
    ``2 / ω`` with ``ω² = authority · Kp``) plus the rotor flapping lag, and the collective lag for the vertical.
    """

    tau_h: float = 0.45  # s, horizontal velocity response
    tau_v: float = 0.35  # s, vertical velocity response


def guided_params(heli: HeliParams | None = None, roll_kp_per_deg: float = 0.045,
                  alt_kd: float = 0.04) -> GuidedParams:
    """Derive the follower's lags from the airframe and the DSP's gains (roll Kp per degree, altitude Kd)."""
    import math

    heli = heli or HeliParams()
    omega = math.sqrt(heli.roll_authority * math.degrees(roll_kp_per_deg))
    tau_h = 2.0 / omega + heli.flap_tau + 0.1  # + the DSP's 50 Hz sampling and reference shaping
    vertical_gain = G * alt_kd / heli.hover_collective + heli.drag_v  # 1/s, velocity error → acceleration
    return GuidedParams(tau_h=tau_h, tau_v=1.0 / vertical_gain + heli.collective_tau)


def guided_model(par: GuidedParams | None = None) -> ca.Function:
    """``f(x, u) → ẋ``: x = n, e, h, vn, ve, vu; u = commanded vn, ve, vu (the follower's input)."""
    import casadi as ca

    par = par or GuidedParams()
    x = ca.SX.sym("x", 6)
    u = ca.SX.sym("u", 3)
    tau = ca.vertcat(par.tau_h, par.tau_h, par.tau_v)
    return ca.Function("guided", [x, u], [ca.vertcat(x[3:6], (u - x[3:6]) / tau)], ["x", "u"], ["dx"])
