"""Kalman filter, control law, planner: hand-computed values, and convergence on simulated data."""

import math

import numpy as np
import pytest

from control.laws import AntiWindup
from modules.uquad import model
from modules.uquad.controller import Controller, SetPoint
from modules.uquad.core import Mode
from modules.uquad.kalman import Kalman, unwrap_theta
from modules.uquad.planner import Planner, PlannerConfig

from .closed_loop import ClosedLoop


@pytest.mark.parametrize("meas,est,expected", [
    (0.5, 0.4, 0.5),                      # within π: unchanged
    (3.0, -3.0, 3.0 - 2 * math.pi),       # across the ±π cut: moved one turn toward the estimate
    (-3.0, 3.0, -3.0 + 2 * math.pi),
    (0.1, 4 * math.pi, 0.1 + 4 * math.pi),  # estimate two turns away: fix((0.1 − 4π − π)/2π) = −2
])
def test_theta_unwrapping_by_hand(meas, est, expected):
    assert unwrap_theta(meas, est) == pytest.approx(expected)


def test_dynamic_covariance_trusts_a_bad_norm_less():
    good, bad = Kalman(), Kalman()
    good.update_attitude((0.2, 0.0, 0.0), 0.0, 0.0)
    bad.update_attitude((0.2, 0.0, 0.0), 0.3, 0.0)  # |acc| 30 % off
    assert 0 < bad.euler[0] < good.euler[0]


def test_control_law_by_hand():
    # K_prop: motor i reacts to the z error with gain 10; K_int: 2 per z integral. sp z = 1, x z = 0.
    k_prop = np.zeros((4, 12))
    k_prop[:, model.IZ] = 10.0
    k_int = np.zeros((4, 4))
    k_int[:, 2] = 2.0
    aw = AntiWindup(th_dist=np.array([9, 9, 9, 9.0]), th_max=np.array([1, 1, 0.5, 1.0]),
                    accum_high=np.array([1, 1, 0.004, 1.0]))
    c = Controller(model.QuadParams(), k_prop, k_int, aw, None, 100.0, 900.0)  # type: ignore[arg-type]
    sp = np.zeros(12)
    sp[model.IZ] = 1.0
    out = c.step(np.zeros(12), SetPoint(sp, np.full(4, 500.0)), ts=0.01)
    # err z = 1; step = clip(1·0.01, ±0.5·0.01) = 0.005 → saturated at th_accum 0.004; ω = 500 + 10 + 2·0.004
    assert out == pytest.approx(np.full(4, 510.008))
    # |err| > th_dist: the integral is held
    c.aw = AntiWindup(th_dist=np.array([9, 9, 0.5, 9.0]), th_max=np.inf, accum_high=np.inf)
    c.step(np.zeros(12), SetPoint(sp, np.full(4, 500.0)), ts=0.01)
    assert c.x_int[2] == pytest.approx(0.004)
    # output clipped to [min, max]
    sp[model.IZ] = 100.0
    assert c.step(np.zeros(12), SetPoint(sp, np.full(4, 500.0)), ts=0.01) == pytest.approx(np.full(4, 900.0))


def test_hover_errors_turn_into_the_yaw_frame():
    c = Controller(model.QuadParams(), np.zeros((4, 12)), np.zeros((4, 4)), AntiWindup(), None, 1, 2, 10.0)
    x = np.zeros(12)
    x[model.ITHETA] = math.pi / 2  # facing world +y
    sp = np.zeros(12)
    sp[model.IY] = 1.0  # target 1 m ahead
    err = c.errors(sp, x)
    assert err[model.IX] == pytest.approx(1.0) and err[model.IY] == pytest.approx(0.0, abs=1e-12)


def test_planner_waypoints_completion_and_new_target_flag():
    p = Planner(PlannerConfig(cruise_speed=1.0, waypoint_radius=0.3, waypoint_speed_max=0.2))
    p.set_mode(Mode.GOTO, np.zeros(3), 0.0)
    p.set_waypoints([np.array([1.0, 0, 0]), np.array([1.0, 1.0, 0])])
    out = p.step(0.0, 0.5, np.zeros(3), np.zeros(3))
    assert out.new_target and out.position == pytest.approx([0.5, 0, 0])  # the carrot: 1 m/s × 0.5 s
    p.step(0.5, 0.5, np.zeros(3), np.zeros(3))
    out = p.step(1.0, 0.1, np.array([1.0, 0.1, 0]), np.zeros(3))  # at the first waypoint, still
    assert p.completed == ["waypoint"] and out.new_target and len(p.waypoints) == 1
    out = p.step(1.1, 0.1, np.array([1.0, 0.1, 0]), np.array([0.5, 0, 0]))  # not reached: fast and far
    assert not out.new_target and p.mode is Mode.GOTO
    p.sp = np.array([1.0, 1.0, 0])
    p.step(2.0, 0.1, np.array([1.0, 1.0, 0]), np.zeros(3))
    assert p.completed == ["waypoint", "waypoint", "goto"] and p.mode is Mode.HOLD


def test_planner_abort_brakes_from_its_velocity_to_a_halt():
    p = Planner(PlannerConfig(accel=2.0))
    p.set_mode(Mode.TAKE_OFF, np.zeros(3), 0.0)
    p.set_mode(Mode.ABORT, np.array([5.0, 0, 3.0]), 0.0, np.array([2.0, 0, 0]))
    out = p.step(0.0, 0.01, np.array([5.0, 0, 3.0]), np.array([2.0, 0, 0]))
    assert out.velocity == pytest.approx([1.98, 0, 0]) and out.position == pytest.approx([5.0198, 0, 3.0])
    for _ in range(100):
        out = p.step(0.0, 0.01, out.position, out.velocity)
    # about v²/2a = 1 m beyond where the abort found it, then held there
    assert out.velocity == pytest.approx([0, 0, 0]) and out.position == pytest.approx([6.0, 0, 3.0], abs=0.02)
    assert p.mode is Mode.ABORT and out.motors_on


@pytest.mark.parametrize("then", ["hold", "reverse", "abort"])
def test_the_set_point_velocity_never_jumps(then):
    """Whatever the ground station asks mid-flight, the set point's velocity changes by about accel·dt a step:
    a hold or an abort at cruise speed, a goto the other way; it ends at rest on its target."""
    p = Planner(PlannerConfig(cruise_speed=2.0, accel=2.0))
    p.set_mode(Mode.TAKE_OFF, np.zeros(3), 0.0)
    p.set_mode(Mode.GOTO, np.zeros(3), 0.0)
    p.set_waypoints([np.array([20.0, 0, 0])])
    velocities = [p.step(0.0, 0.01, p.sp, np.zeros(3)).velocity for _ in range(300)]
    assert velocities[-1] == pytest.approx([2.0, 0, 0])
    if then == "hold":
        p.set_mode(Mode.HOLD, p.sp, 0.0)
    elif then == "abort":
        p.set_mode(Mode.ABORT, p.sp, 0.0, p.sp_velocity)
    else:
        p.set_waypoints([np.array([-5.0, 0, 0])])
    velocities += [p.step(0.0, 0.01, p.sp, np.zeros(3)).velocity for _ in range(1500)]
    jumps = np.linalg.norm(np.diff(np.array(velocities), axis=0), axis=1)
    assert jumps.max() <= 2 * 2.0 * 0.01 + 1e-9, jumps.max()  # a·dt a step; the last, onto the target, 2·a·dt
    assert velocities[-1] == pytest.approx([0, 0, 0])
    if then == "reverse":
        assert p.sp == pytest.approx([-5.0, 0, 0])


@pytest.mark.parametrize("then", ["abort", "hold", "reverse"])
def test_a_stop_or_turn_at_cruise_speed_stays_within_the_control_laws_tilt(then):
    """Closed loop: the aircraft at 2 m/s, then aborted, held or sent back: it tilts far less than the RAL's
    loss-of-control limit (45 degrees; with the set point's velocity jumping it was 44, 45 and 88, a tumble)."""
    loop = ClosedLoop(seed=3)
    loop.run(6.0)
    loop.core.set_mode(Mode.TAKE_OFF)
    loop.run(12.0)
    start = loop.sim.x[:3].copy()
    loop.core.set_waypoints([start + [12.0, 0, 0]])
    loop.core.set_mode(Mode.GOTO)
    while loop.sim.x[0] - start[0] < 3.0:
        loop.run(0.01)
    assert np.linalg.norm(loop.sim.x[6:9]) > 1.8  # at cruise speed
    at = loop.sim.x[0]
    if then == "reverse":
        loop.core.set_waypoints([start - [4.0, 0, 0]])
    else:
        loop.core.set_mode(Mode.ABORT if then == "abort" else Mode.HOLD)
    tilt = []
    for _ in range(600 if then != "reverse" else 1200):
        loop.run(0.01)
        tilt.append(math.degrees(max(abs(loop.sim.x[model.IPHI]), abs(loop.sim.x[model.IPSI]))))
    assert max(tilt) < 25.0, max(tilt)
    assert np.linalg.norm(loop.sim.x[6:9]) < 0.3 and abs(loop.sim.x[2] - start[2]) < 0.5
    if then == "reverse":
        assert np.linalg.norm(loop.sim.x[:2] - (start[:2] - [4.0, 0])) < 0.5
    else:
        assert loop.sim.x[0] - at < 2.0  # stopped within v²/2a (1 m) and the carrot's lead


def test_planner_on_the_ground_ignores_land_and_hold():
    p = Planner()
    p.set_mode(Mode.LAND, np.zeros(3), 0.0)
    assert p.mode is Mode.IDLE and not p.airborne


def test_estimator_converges_and_hovers_on_simulated_data():
    loop = ClosedLoop(seed=5)
    loop.run(5.5)  # 512 still samples calibrate the gyro offset
    assert loop.core.calibrated
    assert loop.core.start.gyro_offset == pytest.approx(loop.sim.noise.gyro_bias, abs=0.002)
    loop.core.set_mode(Mode.TAKE_OFF)
    loop.run(14.0)
    assert "take_off" in loop.core.planner.completed
    late = [(true, est) for t, true, est in loop.trace if t > 15.0]
    pos_err = np.array([np.linalg.norm(true[:3] - est[:3]) for true, est in late])
    att_err = np.array([np.abs(true[3:6] - est[3:6]).max() for true, est in late])
    assert pos_err.max() < 0.5, pos_err.max()
    assert att_err.max() < 0.05, att_err.max()
    assert abs(late[-1][0][model.IZ] - 3.0) < 0.4  # hovering at TAKEOFF_HEIGHT
    # the vertical accelerometer bias is observable through the barometer and GPS: estimated within 50 %
    assert loop.core.kalman.acc_bias[2] == pytest.approx(loop.sim.noise.acc_bias[2], rel=0.5)


def test_setpoint_mode_relinearises_per_target_and_flies_there():
    loop = ClosedLoop(controller_mode="setpoint", seed=7)
    loop.run(5.5)
    loop.core.set_mode(Mode.TAKE_OFF)
    loop.run(9.0)
    assert "take_off" in loop.core.planner.completed
    updates = loop.core.controller.gain_updates
    loop.core.set_waypoints([np.array([3.0, 0.0, 3.0])])
    loop.core.set_mode(Mode.GOTO)
    loop.run(7.0)
    assert loop.core.planner.completed[-2:] == ["waypoint", "goto"]
    assert loop.core.controller.gain_updates > updates  # new LQR gains for the new target
    assert np.linalg.norm(loop.sim.x[:3] - [3.0, 0.0, 3.0]) < 0.5
