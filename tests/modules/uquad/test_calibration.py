"""Calibration formulas against values computed by hand."""

import math
from pathlib import Path

import numpy as np
import pytest

from bbcs.conf import ConfError
from modules.uquad.calibration import (
    G,
    ImuCalibration,
    MotionDuringCalibration,
    SensorCalibration,
    StartCalibration,
    StartCalibrator,
    convert,
    euler_from_acc_mag,
    load_calibration,
    pressure_altitude_m,
)
from modules.uquad.imu_protocol import ImuFrame

ROOT = Path(__file__).resolve().parents[3]
I3 = np.eye(3)


def test_magnetometer_formula_by_hand():
    # T = [[1, 0.1, 0], [0, 1, 0], [0, 0, 1]], K = diag(2, 4, 5), b = (1, 2, 3), raw = (5, 10, 13)
    # raw − b = (4, 8, 10); K⁻¹ · = (2, 2, 2); T · = (2 + 0.2, 2, 2)
    cal = SensorCalibration(T=np.array([[1, 0.1, 0], [0, 1, 0], [0, 0, 1]]), K=np.diag([2.0, 4.0, 5.0]),
                            b=np.array([1.0, 2.0, 3.0]), b_t=np.zeros(3), t0=0.0)
    assert cal.convert(np.array([5, 10, 13])) == pytest.approx([2.2, 2.0, 2.0])


def test_accelerometer_temperature_term_by_hand():
    # raw − b + b_t (t − t0) = (10 − 2 + 0.5·(30 − 20), 0, 0) = (13, 0, 0); K = 10 → 1.3
    cal = SensorCalibration(T=I3, K=10 * I3, b=np.array([2.0, 0, 0]), b_t=np.array([0.5, 0, 0]), t0=20.0)
    assert cal.convert(np.array([10, 0, 0]), temp_c=30.0) == pytest.approx([1.3, 0, 0])
    assert cal.convert(np.array([10, 0, 0])) == pytest.approx([0.8, 0, 0])  # no temperature term without t


def test_euler_level_facing_magnetic_north():
    psi, phi, theta = euler_from_acc_mag(np.array([0, 0, G]), np.array([1.0, 0, 0.5]), 0.17)
    assert (psi, phi) == pytest.approx((0.0, 0.0))
    assert theta == pytest.approx(0.17)  # only the declination


def test_euler_by_hand_pitch_roll_yaw():
    # acc = (−g/2, 0, g·√3/2): φ = −asin(−1/2) = π/6, ψ = −atan2(0, ·) = 0
    psi, phi, theta = euler_from_acc_mag(np.array([-G / 2, 0, G * math.sqrt(3) / 2]), np.array([0, 1.0, 0]), 0.0)
    assert psi == pytest.approx(0.0, abs=1e-12)
    assert phi == pytest.approx(math.pi / 6)
    # M·(0,1,0) = (sinφ·sinψ, cosψ, cosφ·sinψ) = (0, 1, 0) → θ = −atan2(1, 0) = −π/2
    assert theta == pytest.approx(-math.pi / 2)
    # roll: acc = (0, −g·sin(0.3), g·cos(0.3)) → ψ = −atan2(−sin 0.3, cos 0.3) = 0.3
    psi, phi, _ = euler_from_acc_mag(np.array([0, -G * math.sin(0.3), G * math.cos(0.3)]), np.array([1.0, 0, 0]),
                                     0.0)
    assert (psi, phi) == pytest.approx((0.3, 0.0))


def test_euler_near_vertical_uses_the_limit_branch():
    psi, phi, _ = euler_from_acc_mag(np.array([G, 0, 0.01]), np.array([0, 0, 1.0]), 0.0)
    assert phi == pytest.approx(-math.pi / 2) and psi == 0.0


def test_barometric_altitude_by_hand():
    assert pressure_altitude_m(101325.0, 101325.0) == 0.0
    # 44330 · (1 − (100000/101325)^(1/5.255)) = 110.90 m
    assert pressure_altitude_m(100_000.0, 101_325.0) == pytest.approx(110.90, abs=0.01)


def _calib() -> ImuCalibration:
    s = SensorCalibration(T=I3, K=100 * I3, b=np.zeros(3), b_t=np.zeros(3), t0=25.0)
    return ImuCalibration(acc=s, gyro=SensorCalibration(T=I3, K=1000 * I3, b=np.zeros(3), b_t=np.zeros(3), t0=25.0),
                          mag=s, declination_rad=0.0)


def _frame(gyro=(3, -2, 5), acc=(0, 0, 981), pressure=101_000):
    return ImuFrame(10_000, acc, gyro, (100, 0, 0), 250, pressure)


def test_gyro_offset_from_still_samples():
    cal = StartCalibrator(_calib(), samples=4)
    results = [cal.add(_frame()) for _ in range(4)]
    assert results[:3] == [None] * 3
    start = results[3]
    assert start.gyro_offset == pytest.approx([0.003, -0.002, 0.005])
    assert start.p0_pa == 101_000
    data = convert(_frame(gyro=(13, -2, 5)), _calib(), start)
    assert data.gyro == pytest.approx([0.010, 0, 0])
    assert data.altitude_m == pytest.approx(0.0)
    assert data.acc_ok and data.mag_ok


def test_motion_during_calibration_is_refused():
    cal = StartCalibrator(_calib(), samples=8)
    with pytest.raises(MotionDuringCalibration, match="moved"):
        for i in range(8):
            cal.add(_frame(gyro=(200 * (i % 2), 0, 0)))  # ±0.1 rad/s swings
    # after a refusal it starts over and accepts a still set
    assert [cal.add(_frame()) for _ in range(8)][-1] is not None


def test_norm_checks_flag_implausible_vectors():
    start = StartCalibration(gyro_offset=np.zeros(3), p0_pa=101_000, samples=1)
    data = convert(_frame(acc=(0, 0, 2000)), _calib(), start)  # 20 m/s²
    assert not data.acc_ok and data.acc_norm_dev == pytest.approx(20 / G - 1)
    frame = _frame()._replace(mag=(300, 0, 0))  # |m| = 3
    assert not convert(frame, _calib(), start).mag_ok


def test_calibration_file_loads():
    cal = load_calibration(ROOT / "bbcs_conf" / "uquad1_imu_calib.conf")
    assert cal.declination_rad == 0.17
    assert cal.acc.K[1, 1] == 98 and cal.acc.b_t[2] == 2.0 and cal.mag.t0 == 0.0


def test_bad_calibration_file_names_file_and_line(tmp_path):
    bad = tmp_path / "c.conf"
    bad.write_text("IMU_CALIB: acc {\n T = [1 0 0 0 1 0 0 0 1]\n K = [1 2 3]\n b = [0 0 0]\n}\n"
                   "IMU_CALIB: gyro {\n}\nIMU_CALIB: mag {\n}\n")
    with pytest.raises(ConfError) as exc:
        load_calibration(bad)
    assert "c.conf" in str(exc.value) and ":3" in str(exc.value) and "'K'" in str(exc.value)
