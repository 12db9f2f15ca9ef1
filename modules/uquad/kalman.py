"""Extended Kalman filter on position, velocity, attitude and accelerometer bias (seed 002 §1.2.4).

State (12): position x y z (m, local east-north-up), velocity vx vy vz (m/s, world), Euler angles ψ φ θ (rad,
the seed's roll/pitch/yaw), accelerometer bias (m/s², body axes). The body rates are the gyro's (after the start
offset), not states. Prediction integrates the converted accelerometer (minus the bias, rotated to the world,
minus gravity) and the gyro; corrections:

- attitude from accelerometer + magnetometer, θ first unwrapped against the estimate (the seed's rule), with
  the observation noise growing with how far |acc| and |mag| are from their nominal norms (dynamic covariance);
- barometric altitude; GPS position and horizontal velocity when present; zero velocity while on the ground.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from modules.uquad.model import rotation, rotation_and_derivatives

N = 12
P_, V_, E_, B_ = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)
ACC_BOARD_TO_BODY = np.diag([1.0, -1.0, 1.0])
_BOARD_TO_BODY = np.diag(ACC_BOARD_TO_BODY).copy()
_DIAG = np.diag_indices(N)


def unwrap_theta(theta_meas: float, theta_est: float) -> float:
    """The seed's θ correction: keep θ when within π of the estimate, else move it by whole turns toward it."""
    d = theta_meas - theta_est
    if abs(d) < math.pi:
        return theta_meas
    return theta_meas - 2 * math.pi * math.trunc((d + math.pi * math.copysign(1.0, d)) / (2 * math.pi))


def euler_rates(psi: float, phi: float, omega: np.ndarray) -> np.ndarray:
    p, q, r = omega
    sps, cps, tph, cph = math.sin(psi), math.cos(psi), math.tan(phi), math.cos(phi)
    return np.array([p + (q * sps + r * cps) * tph, q * cps - r * sps, (q * sps + r * cps) / cph])


@dataclass
class KalmanNoise:
    acc: float = 0.3  # m/s² (process, velocity)
    gyro: float = 0.02  # rad/s (process, attitude)
    bias: float = 0.002  # m/s² per √s (bias random walk)
    att: float = 0.05  # rad: roll/pitch from acc + mag, nominal, standing still
    att_flight: float = 0.5  # rad: in flight the accelerometer mostly sees the thrust, a poor vertical reference
    yaw: float = 0.08  # rad
    att_norm_gain: float = 400.0
    """σ² multiplier per (norm deviation)²: 10 % off → ×(1 + 4) on the variance."""
    baro: float = 0.4  # m
    gps_pos: float = 0.6  # m
    gps_vel: float = 0.15  # m/s
    still_vel: float = 0.05  # m/s


@dataclass
class Kalman:
    g: float = 9.81
    noise: KalmanNoise = field(default_factory=KalmanNoise)
    x: np.ndarray = field(default_factory=lambda: np.zeros(N))
    P: np.ndarray = field(default_factory=lambda: np.diag([1, 1, 1, 0.5, 0.5, 0.5, 0.1, 0.1, 0.3, 0.2, 0.2, 0.2]))

    def __post_init__(self) -> None:
        self._F = np.eye(N)  # the transition Jacobian, refilled in place each step (its constant part stays)
        self._eye3 = np.eye(3)
        n = self.noise
        self._q_rate = np.zeros(N)  # process noise per second: velocity, attitude, bias
        self._q_rate[V_] = n.acc ** 2
        self._q_rate[E_] = n.gyro ** 2
        self._q_rate[B_] = n.bias ** 2
        self._q_pos = np.zeros(N)  # position: (σ_acc·dt²)², per dt⁴
        self._q_pos[P_] = n.acc ** 2

    def init(self, euler: tuple[float, float, float], altitude: float = 0.0) -> None:
        self.x[:] = 0.0
        self.x[E_] = euler
        self.x[2] = altitude

    # ------------------------------------------------------------ prediction

    def _accel_world(self, x: np.ndarray, acc_body: np.ndarray) -> np.ndarray:
        return rotation(*x[E_]) @ (acc_body - x[B_]) - np.array([0.0, 0.0, self.g])

    def predict(self, acc_board: np.ndarray, gyro: np.ndarray, dt: float) -> None:
        """One prediction step. The Jacobian of the world acceleration with respect to the Euler angles is
        analytic (the derivatives of R = Rz·Ry·Rx), so the step costs one rotation, not four."""
        if not dt > 0:
            return
        x = self.x
        f = np.array(acc_board, dtype=float) * _BOARD_TO_BODY - x[B_]  # specific force, body axes, bias removed
        R, dpsi, dphi, dtheta = rotation_and_derivatives(float(x[6]), float(x[7]), float(x[8]))
        a = R @ f
        a[2] -= self.g
        F = self._F
        F[P_, V_] = self._eye3 * dt
        F[V_, B_] = -R * dt
        F[V_, 6] = (dpsi @ f) * dt
        F[V_, 7] = (dphi @ f) * dt
        F[V_, 8] = (dtheta @ f) * dt
        x[P_] += x[V_] * dt + 0.5 * a * dt * dt
        x[V_] += a * dt
        x[E_] += euler_rates(x[6], x[7], gyro) * dt
        P = F @ self.P @ F.T
        P[_DIAG] += self._q_rate * dt + self._q_pos * (dt ** 4)
        self.P = P

    # ------------------------------------------------------------ corrections

    def _update(self, idx: slice | list[int], z: np.ndarray, r_diag: np.ndarray) -> None:
        """Correction with a selection H (the measured states ``idx``): S = P[idx, idx] + R, K = P[:, idx] S⁻¹,
        written with indexing instead of H products (the same numbers, a fraction of the work)."""
        cols = list(range(N)[idx]) if isinstance(idx, slice) else list(idx)
        P = self.P
        PHt = P[:, cols]
        S = PHt[cols, :] + np.diag(r_diag)
        K = PHt @ np.linalg.inv(S) if len(cols) > 1 else PHt / S[0, 0]
        self.x += K @ (z - self.x[cols])
        self.P = P - K @ P[cols, :]

    def update_attitude(self, euler: tuple[float, float, float], acc_norm_dev: float, mag_norm_dev: float,
                        flying: bool = False) -> None:
        psi, phi, theta = euler
        theta = unwrap_theta(theta, self.x[8])
        n = self.noise
        k_acc = 1.0 + n.att_norm_gain * acc_norm_dev ** 2
        k_mag = 1.0 + n.att_norm_gain * mag_norm_dev ** 2
        att = n.att_flight if flying else n.att
        r = np.array([att ** 2 * k_acc, att ** 2 * k_acc, n.yaw ** 2 * k_acc * k_mag])
        self._update(E_, np.array([psi, phi, theta]), r)
        self.x[8] = (self.x[8] + math.pi) % (2 * math.pi) - math.pi

    def update_altitude(self, z: float) -> None:
        self._update([2], np.array([z]), np.array([self.noise.baro ** 2]))

    def update_gps(self, east: float, north: float, ve: float, vn: float) -> None:
        n = self.noise
        self._update([0, 1, 3, 4], np.array([east, north, ve, vn]),
                     np.array([n.gps_pos ** 2, n.gps_pos ** 2, n.gps_vel ** 2, n.gps_vel ** 2]))

    def update_still(self) -> None:
        self._update(V_, np.zeros(3), np.full(3, self.noise.still_vel ** 2))

    # ------------------------------------------------------------ views

    @property
    def position(self) -> np.ndarray:
        return self.x[P_]

    @property
    def velocity(self) -> np.ndarray:
        return self.x[V_]

    @property
    def euler(self) -> np.ndarray:
        return self.x[E_]

    @property
    def acc_bias(self) -> np.ndarray:
        return self.x[B_]
