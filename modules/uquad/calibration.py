"""IMU calibration and conversion (seed 002 §1.2.3): raw ADC counts → SI units, Euler angles, altitude.

- magnetometer: ``conv = T · K⁻¹ · (raw − b)`` (1.1)
- accelerometer: ``conv = T · K⁻¹ · (raw − b + b_t (t − t0))`` (1.2), m/s²
- gyro: like the accelerometer, then minus the offset estimated at start while standing still, rad/s
- Euler angles from accelerometer + magnetometer with the seed's formulas, the declination from the .conf
- barometric altitude relative to the pressure measured during the start calibration

Calibration parameters are read from a file in the .conf format (docs/uquad.md §3). Pure functions and plain
classes: no I/O besides ``load_calibration``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bbcs import ConfError, ConfGroup, load_conf
from modules.uquad.imu_protocol import ImuFrame

G = 9.81
GYRO_CALIB_SAMPLES = 512


@dataclass(frozen=True)
class SensorCalibration:
    """``T`` (3×3, cross-axis), ``K`` (3×3 gains), ``b`` (offset, counts), ``b_t`` (counts per °C), ``t0`` (°C)."""

    T: np.ndarray
    K: np.ndarray
    b: np.ndarray
    b_t: np.ndarray
    t0: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "_TKinv", self.T @ np.linalg.inv(self.K))

    def convert(self, raw: np.ndarray, temp_c: float | None = None) -> np.ndarray:
        """``T · K⁻¹ · (raw − b [+ b_t (t − t0)])``: the temperature term only when ``temp_c`` is given."""
        x = np.asarray(raw, dtype=float) - self.b
        if temp_c is not None:
            x = x + self.b_t * (temp_c - self.t0)
        return self._TKinv @ x  # type: ignore[attr-defined]


@dataclass(frozen=True)
class ImuCalibration:
    acc: SensorCalibration
    gyro: SensorCalibration
    mag: SensorCalibration
    declination_rad: float
    """Added to θ: the local magnetic field does not point to true north (0.17 rad in the seed's Uruguay)."""
    acc_norm_tol: float = 0.15
    """|acc| outside g·(1 ± tol) is flagged as implausible."""
    mag_norm: float = 1.0
    mag_norm_tol: float = 0.2


def _vector(group: ConfGroup, key: str, n: int) -> np.ndarray:
    value = group.get(key)
    if not isinstance(value, list) or len(value) != n:
        entry = group.entries.get(key)
        raise ConfError(f"key {key!r} in group '{group.label}' must be a list of {n} numbers",
                        path=group.path, line=entry.line if entry else group.line)
    try:
        return np.array([float(v) for v in value])
    except ValueError as exc:
        entry = group.entries[key]
        raise ConfError(f"key {key!r} in group '{group.label}': {exc}", path=group.path, line=entry.line) from None


def _sensor(group: ConfGroup) -> SensorCalibration:
    K = _vector(group, "K", 9).reshape(3, 3)
    if abs(np.linalg.det(K)) < 1e-12:
        raise ConfError(f"group '{group.label}': K is singular", path=group.path, line=group.line)
    b_t = _vector(group, "b_t", 3) if "b_t" in group.entries else np.zeros(3)
    t0 = float(group.require("t0")) if "t0" in group.entries else 0.0
    return SensorCalibration(T=_vector(group, "T", 9).reshape(3, 3), K=K, b=_vector(group, "b", 3), b_t=b_t, t0=t0)


def load_calibration(path: str | Path) -> ImuCalibration:
    """Read ``IMU_CALIB: acc|gyro|mag { T K b [b_t t0] }`` groups and the scalar keys; ConfError names file:line."""
    doc = load_conf(path)

    def number(key: str, default: float) -> float:
        raw = doc.get(key)
        if raw is None:
            return default
        try:
            return float(raw)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            entry = doc.entries[key]
            raise ConfError(f"key {key!r} must be a number, got {raw!r}", path=doc.path, line=entry.line) from None

    return ImuCalibration(
        acc=_sensor(doc.group("IMU_CALIB", "acc")),
        gyro=_sensor(doc.group("IMU_CALIB", "gyro")),
        mag=_sensor(doc.group("IMU_CALIB", "mag")),
        declination_rad=number("DECLINATION_RAD", 0.0),
        acc_norm_tol=number("ACC_NORM_TOL", 0.15),
        mag_norm=number("MAG_NORM", 1.0),
        mag_norm_tol=number("MAG_NORM_TOL", 0.2),
    )


# ---------------------------------------------------------------- angles and altitude

def euler_from_acc_mag(acc: np.ndarray, mag: np.ndarray, declination_rad: float) -> tuple[float, float, float]:
    """The seed's formulas: (ψ, φ, θ) in radians: roll ψ, pitch φ, yaw θ (seed naming)."""
    ax, ay, az = (float(v) for v in acc)
    norm = math.sqrt(ax * ax + ay * ay + az * az)
    if abs(ax) < 0.99 * norm:
        phi = -math.asin(ax / norm)
        psi = -math.atan2(ay, az)
    else:
        phi = -math.pi / 2 * math.copysign(1.0, ax)
        psi = 0.0
    cf, sf, cp, sp = math.cos(phi), math.sin(phi), math.cos(psi), math.sin(psi)
    M = np.array([[cf, sf * sp, cp * sf],
                  [0.0, cp, -sp],
                  [-sf, cf * sp, cf * cp]])
    v = M @ np.asarray(mag, dtype=float)
    theta = -math.atan2(v[1], v[0]) + declination_rad
    return psi, phi, theta


def pressure_altitude_m(pressure_pa: float, p0_pa: float) -> float:
    """Height above the level where the pressure is ``p0_pa`` (international barometric formula)."""
    return 44_330.0 * (1.0 - (pressure_pa / p0_pa) ** (1.0 / 5.255))


# ---------------------------------------------------------------- converted sample

@dataclass(frozen=True)
class ImuData:
    """A converted IMU sample. ``acc`` in the board's accelerometer axes (docs/uquad.md §3.2)."""

    acc: np.ndarray
    gyro: np.ndarray
    mag: np.ndarray
    euler: tuple[float, float, float]
    temp_c: float
    altitude_m: float
    acc_ok: bool
    mag_ok: bool
    acc_norm_dev: float
    """|acc|/g − 1: how far from a plausible static reading (the Kalman filter's dynamic covariance)."""
    mag_norm_dev: float
    loop_us: int


class MotionDuringCalibration(Exception):
    """The quadrotor moved while the gyro offset was being estimated: the offset would be wrong."""


@dataclass(frozen=True)
class StartCalibration:
    gyro_offset: np.ndarray
    p0_pa: float
    samples: int


class StartCalibrator:
    """Accumulates still samples (512 by default) to estimate the gyro offset and the reference pressure.

    Motion is detected from the spread of the samples: a gyro standard deviation above ``gyro_std_max`` (rad/s)
    or an accelerometer-norm standard deviation above ``acc_std_max`` (m/s²) on the whole set refuses the
    calibration (``MotionDuringCalibration``); the caller starts over.
    """

    def __init__(self, calib: ImuCalibration, samples: int = GYRO_CALIB_SAMPLES, gyro_std_max: float = 0.02,
                 acc_std_max: float = 0.3) -> None:
        if samples < 2:
            raise ValueError("calibration needs at least 2 samples")
        self.calib = calib
        self.samples = samples
        self.gyro_std_max = gyro_std_max
        self.acc_std_max = acc_std_max
        self._gyro: list[np.ndarray] = []
        self._acc_norm: list[float] = []
        self._pressure: list[float] = []

    def add(self, frame: ImuFrame) -> StartCalibration | None:
        """Add one frame; returns the result once ``samples`` frames are in (raises if they show motion)."""
        t = frame.temp_x10 / 10.0
        self._gyro.append(self.calib.gyro.convert(np.array(frame.gyro), t))
        self._acc_norm.append(float(np.linalg.norm(self.calib.acc.convert(np.array(frame.acc), t))))
        self._pressure.append(float(frame.pressure_pa))
        if len(self._gyro) < self.samples:
            return None
        gyro = np.array(self._gyro)
        gyro_std = gyro.std(axis=0)
        acc_std = float(np.std(self._acc_norm))
        self._gyro.clear()
        self._acc_norm.clear()
        pressure = float(np.mean(self._pressure))
        self._pressure.clear()
        if (gyro_std > self.gyro_std_max).any() or acc_std > self.acc_std_max:
            raise MotionDuringCalibration(
                f"moved during calibration: gyro std {np.round(gyro_std, 4).tolist()} rad/s "
                f"(max {self.gyro_std_max}), |acc| std {acc_std:.3f} m/s² (max {self.acc_std_max})")
        return StartCalibration(gyro_offset=gyro.mean(axis=0), p0_pa=pressure, samples=self.samples)


def convert(frame: ImuFrame, calib: ImuCalibration, start: StartCalibration) -> ImuData:
    """Raw frame → SI units, angles, altitude and the two norm flags."""
    t = frame.temp_x10 / 10.0
    acc = calib.acc.convert(np.array(frame.acc), t)
    gyro = calib.gyro.convert(np.array(frame.gyro), t) - start.gyro_offset
    mag = calib.mag.convert(np.array(frame.mag))
    acc_dev = float(np.linalg.norm(acc)) / G - 1.0
    mag_dev = float(np.linalg.norm(mag)) / calib.mag_norm - 1.0
    return ImuData(
        acc=acc, gyro=gyro, mag=mag,
        euler=euler_from_acc_mag(acc, mag, calib.declination_rad),
        temp_c=t,
        altitude_m=pressure_altitude_m(frame.pressure_pa, start.p0_pa),
        acc_ok=abs(acc_dev) <= calib.acc_norm_tol,
        mag_ok=abs(mag_dev) <= calib.mag_norm_tol,
        acc_norm_dev=acc_dev, mag_norm_dev=mag_dev, loop_us=frame.loop_us,
    )
