"""The lean Kalman step (analytic Jacobian, indexed corrections) gives the textbook EKF's numbers: a reference
written the long way (selection matrices H, the Jacobian by finite differences) is run on the same inputs."""

from __future__ import annotations

import math

import numpy as np

from modules.uquad import model
from modules.uquad.kalman import ACC_BOARD_TO_BODY, B_, E_, P_, V_, Kalman, N, euler_rates


class Reference:
    def __init__(self, k: Kalman) -> None:
        self.g, self.n = k.g, k.noise
        self.x, self.P = k.x.copy(), k.P.copy()

    def accel(self, x: np.ndarray, acc_body: np.ndarray) -> np.ndarray:
        return model.rotation(*x[E_]) @ (acc_body - x[B_]) - np.array([0.0, 0.0, self.g])

    def predict(self, acc_board: np.ndarray, gyro: np.ndarray, dt: float) -> None:
        acc_body = ACC_BOARD_TO_BODY @ acc_board
        x = self.x
        a = self.accel(x, acc_body)
        F = np.eye(N)
        F[P_, V_] = np.eye(3) * dt
        F[V_, B_] = -model.rotation(*x[E_]) * dt
        for i in range(3):
            e = np.zeros(N)
            e[6 + i] = 1e-6
            F[V_, 6 + i] = (self.accel(x + e, acc_body) - self.accel(x - e, acc_body)) / 2e-6 * dt
        x[P_] += x[V_] * dt + 0.5 * a * dt * dt
        x[V_] += a * dt
        x[E_] += euler_rates(x[6], x[7], gyro) * dt
        n = self.n
        Q = np.zeros(N)
        Q[P_] = (n.acc * dt * dt) ** 2
        Q[V_] = n.acc ** 2 * dt
        Q[E_] = n.gyro ** 2 * dt
        Q[B_] = n.bias ** 2 * dt
        self.P = F @ self.P @ F.T + np.diag(Q)

    def update(self, cols: list[int], z: np.ndarray, r: np.ndarray) -> None:
        H = np.zeros((len(cols), N))
        H[range(len(cols)), cols] = 1.0
        S = H @ self.P @ H.T + np.diag(r)
        K = self.P @ H.T @ np.linalg.inv(S)
        self.x = self.x + K @ (z - H @ self.x)
        self.P = (np.eye(N) - K @ H) @ self.P


def test_lean_steps_equal_the_textbook_filter() -> None:
    rng = np.random.default_rng(11)
    k = Kalman()
    k.init((0.05, -0.03, 1.0), 2.0)
    ref = Reference(k)
    for step in range(300):
        acc = np.array([0.3, -0.2, 9.81]) + rng.normal(0, 0.5, 3)
        gyro = rng.normal(0, 0.2, 3)
        dt = 0.01 + rng.uniform(-0.002, 0.002)
        k.predict(acc, gyro, dt)
        ref.predict(acc, gyro, dt)
        z_att = np.array([0.05, -0.03, 1.0]) + rng.normal(0, 0.05, 3)
        r_att = np.array([0.01, 0.01, 0.02])
        k._update(E_, z_att, r_att)
        ref.update([6, 7, 8], z_att, r_att)
        z_alt = 2.0 + rng.normal(0, 0.3)
        k.update_altitude(z_alt)
        ref.update([2], np.array([z_alt]), np.array([k.noise.baro ** 2]))
        if step % 20 == 0:
            gps = np.array([0.1, -0.1, 0.0, 0.0]) + rng.normal(0, 0.3, 4)
            k.update_gps(*gps)
            ref.update([0, 1, 3, 4], gps, np.array([k.noise.gps_pos ** 2] * 2 + [k.noise.gps_vel ** 2] * 2))
        if step % 50 == 0:
            assert np.allclose(k.x, ref.x, rtol=1e-6, atol=1e-8), step
            assert np.allclose(k.P, ref.P, rtol=1e-5, atol=1e-10), step
    assert np.allclose(k.x, ref.x, rtol=1e-6, atol=1e-8)
    assert np.allclose(k.P, ref.P, rtol=1e-5, atol=1e-10)
    assert math.isfinite(float(k.P.sum()))
