"""Seed 002's control laws on hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from control.laws import (
    AntiWindup,
    integral_action,
    integrate,
    integrate_scalar,
    proportional,
    saturate,
    total_action,
)
from control.pid import Pid, PidGains


def test_proportional_matrix_and_scalar() -> None:
    k = np.array([[2.0, 0.0], [1.0, -1.0]])
    # sp − x = (1, −2): (2·1, 1·1 − 1·(−2)) = (2, 3)
    assert proportional(k, [3.0, 0.0], [2.0, 2.0]).tolist() == [2.0, 3.0]
    assert proportional(0.5, 4.0, 1.0) == pytest.approx(1.5)


def test_integral_skips_large_errors() -> None:
    aw = AntiWindup(th_dist=1.0)
    assert integrate(0.3, 1.5, 0.1, aw) == pytest.approx(0.3)  # |err| > th_dist: unchanged
    assert integrate(0.3, -0.5, 0.1, aw) == pytest.approx(0.25)  # 0.3 + (−0.5·0.1)


def test_integral_step_clamped_to_th_max_times_ts() -> None:
    aw = AntiWindup(th_dist=10.0, th_max=2.0)
    # err·Ts = 5·0.1 = 0.5 > th_max·Ts = 0.2 → +0.2
    assert integrate(1.0, 5.0, 0.1, aw) == pytest.approx(1.2)
    assert integrate(1.0, -5.0, 0.1, aw) == pytest.approx(0.8)
    assert integrate(1.0, 1.0, 0.1, aw) == pytest.approx(1.1)  # below the clamp: err·Ts


def test_integral_accumulator_saturates() -> None:
    aw = AntiWindup(th_max=100.0, accum_high=1.0)
    assert integrate(0.95, 2.0, 0.1, aw) == pytest.approx(1.0)  # 1.15 → 1.0
    assert integrate(-0.95, -2.0, 0.1, aw) == pytest.approx(-1.0)  # symmetric ± th_accum
    asym = AntiWindup(accum_high=1.0, accum_low=-0.2)
    assert integrate(0.0, -5.0, 0.1, asym) == pytest.approx(-0.2)


def test_integral_elementwise_thresholds() -> None:
    aw = AntiWindup(th_dist=np.array([1.0, 10.0]), th_max=np.array([100.0, 1.0]), accum_high=np.array([5.0, 5.0]))
    got = integrate([0.0, 0.0], [2.0, 3.0], 0.5, aw)
    assert got.tolist() == pytest.approx([0.0, 0.5])  # first: |2|>1 skipped; second: 1.5 clamped to 1·0.5


@pytest.mark.parametrize(("prev", "err", "ts"), [(0.3, 1.5, 0.1), (0.3, -0.5, 0.1), (0.9, 5.0, 0.3), (-0.9, -9.0, 1.0)])
def test_scalar_integral_matches_the_array_form(prev: float, err: float, ts: float) -> None:
    aw = AntiWindup(th_dist=6.0, th_max=2.0, accum_high=1.0, accum_low=-0.95)
    assert integrate_scalar(prev, err, ts, 6.0, 2.0, -0.95, 1.0) == pytest.approx(float(integrate(prev, err, ts, aw)))


def test_integral_refuses_non_positive_period() -> None:
    with pytest.raises(ValueError):
        integrate(0.0, 1.0, 0.0, AntiWindup())


def test_total_action_and_integral_action() -> None:
    w_int = integral_action(np.diag([2.0, 3.0]), [0.5, -1.0])
    assert w_int.tolist() == [1.0, -3.0]
    assert total_action([100.0, 100.0], [1.0, 2.0], w_int).tolist() == [102.0, 99.0]


def test_saturate_and_bad_limits() -> None:
    assert saturate([-3.0, 0.5, 3.0], -1.0, 1.0).tolist() == [-1.0, 0.5, 1.0]
    with pytest.raises(ValueError):
        saturate(0.0, 1.0, -1.0)


def test_pid_measures_its_period_from_the_callers_clock() -> None:
    g = PidGains(kp=2.0, ki=1.0, kd=0.5, offset=0.1, awu_max=10.0, awu_min=-10.0, th_dist=5.0, th_max=100.0)
    pid = Pid(g)
    # first call: no period yet → no integral, no derivative: 0.1 + 2·1 = 2.1
    assert pid.step(10.0, x=0.0, sp=1.0) == pytest.approx(2.1)
    # 0.2 s later, err 2: integral 0.4, derivative (2−1)/0.2 = 5 → 0.1 + 4 + 0.4 + 2.5 = 7.0
    assert pid.step(10.2, x=-1.0, sp=1.0) == pytest.approx(7.0)
    # a late step (0.5 s): integral 0.4 + 2·0.5 = 1.4, derivative 0 → 0.1 + 4 + 1.4 = 5.5
    assert pid.step(10.7, x=-1.0, sp=1.0) == pytest.approx(5.5)
    assert pid.step(10.7, x=50.0, sp=1.0) == pytest.approx(5.5)  # same instant: unchanged


def test_pid_anti_windup_and_output_saturation() -> None:
    g = PidGains(kp=0.0, ki=1.0, awu_max=0.3, awu_min=-0.3, sat_high=0.25, sat_low=-1.0, th_dist=2.0,
                 th_max=1.0, reference=0.0)
    pid = Pid(g)
    pid.step(0.0, x=-1.0)
    for k in range(1, 11):
        pid.step(k * 0.1, x=-1.0)  # err 1 (within th_dist), 0.1 per step, accumulator stops at 0.3
    assert pid.integral == pytest.approx(0.3)
    assert pid.output == pytest.approx(0.25)  # Ki·0.3 = 0.3 saturated at sat_encima
    pid.step(1.1, x=3.0)  # err −3: beyond th_dist, not integrated
    assert pid.integral == pytest.approx(0.3)


def test_pid_rate_input_and_reset() -> None:
    pid = Pid(PidGains(kp=1.0, kd=0.1, integral=0.7, ki=1.0))
    assert pid.step(0.0, x=0.0, sp=1.0, rate=-20.0) == pytest.approx(1.0 + 0.7 - 2.0)
    pid.reset()
    assert pid.integral == 0.7


def test_pid_gains_limits_in_order() -> None:
    with pytest.raises(ValueError):
        PidGains(kp=1.0, awu_max=-1.0, awu_min=1.0)
    assert math.isinf(PidGains(kp=1.0).sat_high)
