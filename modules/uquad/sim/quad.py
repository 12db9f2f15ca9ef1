"""The simulated quadrotor: rigid body, first-order motors, ground contact, and sensors that produce the IMU's
raw ADC counts through the inverse of the board's calibration, with noise, a gyro bias (the start calibration
estimates it), an accelerometer bias (the estimator's bias states track it) and a slow temperature drift.
Faults can be injected: :meth:`QuadSim.fail_motor` makes a motor give a share of its thrust and torque (0: a motor
or propeller lost), the simulator's control port sets it from outside (modules/uquad/sim/server.py).

Pure apart from a seeded RNG: ``step(dt)`` advances the physics; ``imu_frame()``/``gps_fix()`` sample sensors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from modules.uquad import model
from modules.uquad.calibration import ImuCalibration, SensorCalibration
from modules.uquad.geo import Home
from modules.uquad.gps import GpsFix
from modules.uquad.imu_protocol import ImuFrame

BOARD_ACC_AXES = np.diag([1.0, -1.0, 1.0])
"""The board's accelerometer axes relative to the body's (its y axis is reversed; docs/uquad.md §3.2)."""
SEA_LEVEL_PA = 101_325.0


@dataclass
class SensorNoise:
    acc_sigma: float = 0.05  # m/s²
    gyro_sigma: float = 0.004  # rad/s
    mag_sigma: float = 0.01
    pressure_sigma: float = 2.0  # Pa (≈ 0.17 m)
    gps_sigma: float = 0.3  # m
    gps_vel_sigma: float = 0.05  # m/s
    gyro_bias: tuple[float, float, float] = (0.02, -0.015, 0.01)
    acc_bias: tuple[float, float, float] = (0.08, -0.05, 0.1)


@dataclass
class QuadSim:
    params: model.QuadParams
    calib: ImuCalibration
    home: Home
    noise: SensorNoise = field(default_factory=SensorNoise)
    seed: int = 1
    magnetic_inclination_rad: float = -0.6
    x: np.ndarray = field(default_factory=lambda: np.zeros(model.N_STATES))
    w: np.ndarray = field(default_factory=lambda: np.zeros(model.N_MOTORS))
    w_cmd: np.ndarray = field(default_factory=lambda: np.zeros(model.N_MOTORS))
    t: float = 0.0
    on_ground: bool = True
    motor_efficiency: np.ndarray = field(default_factory=lambda: np.ones(model.N_MOTORS))
    """Share of each motor's thrust and torque actually produced (1 healthy, 0 lost): the fault injection."""

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        self._acc_world = np.zeros(3)
        d, i = self.calib.declination_rad, self.magnetic_inclination_rad
        # the field points `declination` counter-clockwise from world x: the seed's θ formula then gives true yaw
        self.mag_world = np.array([math.cos(i) * math.cos(d), math.cos(i) * math.sin(d), math.sin(i)])

    # ------------------------------------------------------------ physics

    def command(self, speeds: np.ndarray | list[float]) -> None:
        self.w_cmd = np.asarray(speeds, dtype=float).copy()

    def fail_motor(self, motor: int, efficiency: float = 0.0) -> None:
        """From now on motor ``motor`` (0-3) produces ``efficiency`` (0…1) of its thrust; 1 repairs it."""
        if not 0 <= motor < model.N_MOTORS:
            raise ValueError(f"motor must be 0..{model.N_MOTORS - 1}, not {motor}")
        if not 0.0 <= efficiency <= 1.0:
            raise ValueError(f"efficiency must be in [0, 1], not {efficiency}")
        self.motor_efficiency[motor] = efficiency

    def step(self, dt: float) -> None:
        p = self.params
        self.w += (self.w_cmd - self.w) * min(1.0, dt / p.motor_tau)
        w = self.w * np.sqrt(self.motor_efficiency)  # thrust and torque go with w²: a share of both
        d = np.array(model.rates(self.x, w, p))
        if self.on_ground:
            thrust = p.k_thrust * float(np.sum(w ** 2))
            if thrust <= p.mass * p.g * 1.001:
                self._acc_world = np.zeros(3)
                self.x[model.IVX:] = 0.0
                return
            self.on_ground = False
        self.x += d * dt
        self._acc_world = d[model.IVX:model.IVZ + 1]
        if self.x[model.IZ] <= 0.0 and self.x[model.IVZ] <= 0.0:  # touch-down: the ground holds it level
            self.x[model.IZ] = 0.0
            self.x[model.IPSI] = self.x[model.IPHI] = 0.0
            self.x[model.IVX:] = 0.0
            self._acc_world = np.zeros(3)
            self.on_ground = True

    # ------------------------------------------------------------ sensors

    @staticmethod
    def _raw(cal: SensorCalibration, conv: np.ndarray, temp_c: float | None) -> tuple[int, int, int]:
        raw = cal.K @ np.linalg.solve(cal.T, conv) + cal.b
        if temp_c is not None:
            raw = raw - cal.b_t * (temp_c - cal.t0)
        return tuple(int(v) for v in np.clip(np.round(raw), -32768, 32767))  # type: ignore[return-value]

    def temperature_c(self) -> float:
        return 25.0 + 3.0 * math.sin(self.t / 600.0)

    def imu_frame(self) -> ImuFrame:
        n, rng = self.noise, self.rng
        r = model.rotation(*self.x[model.IPSI:model.ITHETA + 1])
        specific = r.T @ (self._acc_world + np.array([0.0, 0.0, self.params.g]))
        acc = BOARD_ACC_AXES @ (specific + np.array(n.acc_bias)) + rng.normal(0, n.acc_sigma, 3)
        gyro = self.x[model.IP:] + np.array(n.gyro_bias) + rng.normal(0, n.gyro_sigma, 3)
        mag = r.T @ self.mag_world + rng.normal(0, n.mag_sigma, 3)
        temp = self.temperature_c()
        alt = self.home.alt + self.x[model.IZ]
        pressure = SEA_LEVEL_PA * (1 - alt / 44_330.0) ** 5.255 + rng.normal(0, n.pressure_sigma)
        return ImuFrame(
            loop_us=int(rng.integers(9_000, 9_990)),
            acc=self._raw(self.calib.acc, acc, temp),
            gyro=self._raw(self.calib.gyro, gyro, temp),
            mag=self._raw(self.calib.mag, mag, None),
            temp_x10=round(temp * 10),
            pressure_pa=round(pressure),
        )

    def gps_fix(self) -> GpsFix:
        n, rng = self.noise, self.rng
        e, no, u = self.x[model.IX:model.IZ + 1] + rng.normal(0, n.gps_sigma, 3)
        lat, lon, alt = self.home.to_geo(e, no, u)
        ve, vn = self.x[model.IVX:model.IVY + 1] + rng.normal(0, n.gps_vel_sigma, 2)
        return GpsFix(lat=lat, lon=lon, alt=alt, ve=float(ve), vn=float(vn), satellites=9, quality=1)
