"""The ground station's task parameters in the uQuad's planner (issue 16): the take-off height, the goto speed
and the seed's manual mode (set-point steps), whatever order mode and parameters arrive in; refusals change
nothing. Then in closed loop (simulator physics, FlightCore, the driver's logic): the quadrotor really climbs
to the height asked, and manual steps move it while every motor command stays in [MOTOR_MIN, MOTOR_MAX]."""

from __future__ import annotations

import numpy as np
import pytest

from bbcs.contracts import tasks as t
from modules.uquad.config import load_config
from modules.uquad.gps import LocalGps
from modules.uquad.planner import Mode, Planner, PlannerConfig, apply_task

from .closed_loop import ROOT, ClosedLoop

CFG = PlannerConfig(takeoff_height=3.0, cruise_speed=1.0, climb_speed=1.0, max_height=20.0)


def climb_target(p: Planner, seconds: float = 30.0) -> float:
    """Where the take-off carrot ends (z), stepping with the estimate on the set point."""
    for i in range(int(seconds / 0.1)):
        p.step(i * 0.1, 0.1, p.sp.copy(), np.zeros(3))
    return float(p.sp[2])


@pytest.mark.parametrize("params_first", [False, True])
def test_take_off_climbs_to_the_task_height_whichever_arrives_first(params_first: bool) -> None:
    p = Planner(CFG)
    if params_first:
        assert apply_task(p, t.TakeOff(height=5.5)) == ""
    p.set_mode(Mode.TAKE_OFF, np.array([0.0, 0.0, 1.0]), 0.0)
    if not params_first:
        assert apply_task(p, t.TakeOff(height=5.5)) == ""
    assert climb_target(p) == pytest.approx(6.5)  # ground at 1 m + 5.5 m
    assert p.completed == ["take_off"] and p.mode is Mode.HOLD


def test_without_a_task_height_the_default_is_climbed_and_a_height_above_the_ceiling_is_refused() -> None:
    p = Planner(CFG)
    why = apply_task(p, t.TakeOff(height=25.0))
    assert "25" in why and "20" in why and p.takeoff_height is None
    p.set_mode(Mode.TAKE_OFF, np.zeros(3), 0.0)
    assert climb_target(p) == pytest.approx(3.0)


def test_goto_speed_drives_the_carrot() -> None:
    p = Planner(CFG)
    p.set_mode(Mode.TAKE_OFF, np.zeros(3), 0.0)
    climb_target(p)
    p.set_mode(Mode.GOTO, p.sp.copy(), 0.0)
    p.set_waypoints([np.array([10.0, 0.0, 3.0])])
    assert apply_task(p, t.Goto(waypoints=[t.Waypoint(lat=0, lon=0, alt=3)], speed=2.5)) == ""
    outs = [p.step(0.0, 0.01, p.sp.copy(), np.zeros(3)) for _ in range(200)]
    # it speeds up at the set point's acceleration (2 m/s²), then cruises at the task's 2.5 m/s, not CRUISE_SPEED
    assert outs[49].velocity[0] == pytest.approx(1.0) and outs[-1].velocity[0] == pytest.approx(2.5)
    assert outs[-1].position[0] - outs[-2].position[0] == pytest.approx(0.025)
    assert apply_task(p, t.Hold()) == ""  # kinds without parameters change nothing


def test_manual_steps_move_the_hover_target_and_refusals_change_nothing() -> None:
    p = Planner(CFG)
    assert "on the ground" in apply_task(p, t.Manual(up=1.0))
    assert p.mode is Mode.IDLE and p.manual_target is None
    p.set_mode(Mode.MANUAL, np.zeros(3), 0.0)  # the mode alone does not lift it off the ground
    assert p.mode is Mode.IDLE
    p.set_mode(Mode.TAKE_OFF, np.zeros(3), 0.0)
    climb_target(p)
    p.set_mode(Mode.MANUAL, p.sp.copy(), 0.0)
    assert p.manual_target == pytest.approx([0.0, 0.0, 3.0])  # hovers where it is until the first command
    assert apply_task(p, t.Manual(east=2.0, up=1.0, yaw=30.0)) == ""
    assert apply_task(p, t.Manual(north=-1.0)) == ""  # relative to the last target, not the carrot
    assert p.manual_target == pytest.approx([2.0, -1.0, 4.0]) and p.yaw == pytest.approx(np.radians(30))
    p.set_mode(Mode.MANUAL, p.sp.copy(), 0.0)  # the next manual task's mode keeps the target
    assert p.manual_target == pytest.approx([2.0, -1.0, 4.0])
    assert climb_target(p, 10.0) == pytest.approx(4.0) and p.sp == pytest.approx([2.0, -1.0, 4.0])
    for bad in (t.Manual(up=-4.0), t.Manual(up=5.0, north=1.0)):
        p.cfg = PlannerConfig(max_height=8.0)
        before = (p.manual_target.copy(), p.yaw, p.mode)
        why = apply_task(p, bad)
        assert "outside" in why
        assert (p.manual_target, p.yaw, p.mode) == (pytest.approx(before[0]), before[1], before[2])


def test_closed_loop_climbs_to_the_asked_height_and_manual_keeps_the_motors_in_range() -> None:
    v = load_config(ROOT / "bbcs_conf" / "uquad1.conf").values
    loop = ClosedLoop(seed=7)
    loop.run(5.5)
    assert loop.core.calibrated
    assert apply_task(loop.core.planner, t.TakeOff(height=5.0)) == ""
    loop.core.set_mode(Mode.TAKE_OFF)
    commands: list[tuple[float, ...]] = []
    real = loop.driver.on_command
    loop.driver.on_command = lambda now, cmd: (commands.append(cmd), real(now, cmd))[1]  # type: ignore[method-assign]
    loop.run(14.0)
    assert "take_off" in loop.core.planner.completed
    assert loop.sim.x[2] == pytest.approx(5.0, abs=0.4)  # the truth, not the estimate
    loop.core.set_mode(Mode.MANUAL)
    assert apply_task(loop.core.planner, t.Manual(east=1.5, up=2.0)) == ""
    loop.run(10.0)
    assert loop.sim.x[0] == pytest.approx(1.5, abs=0.4) and loop.sim.x[2] == pytest.approx(7.0, abs=0.4)
    flying = [c for c in commands if any(c)]
    assert flying and all(v.MOTOR_MIN <= w <= v.MOTOR_MAX for c in flying for w in c)


def test_closed_loop_with_reads_of_several_frames_still_flies() -> None:
    """A loaded flight loop reads 1 to 6 frames at a time: one estimator and control step per read (on the mean)
    still takes off and holds the height."""
    rng = np.random.default_rng(3)
    loop = ClosedLoop(seed=9)
    loop.run(5.5)
    assert loop.core.calibrated
    loop.core.set_mode(Mode.TAKE_OFF)
    pending = []
    heights = []
    for tick in range(1600):  # 16 s
        for _ in range(5):
            loop.sim.step(0.002)
        t_now = 5.5 + (tick + 1) * 0.01
        loop.sim.t = t_now
        pending.append(loop.sim.imu_frame())
        if len(pending) >= rng.integers(1, 7):
            cmd = loop.core.on_frames(pending, t_now)
            pending = []
            if cmd is not None:
                loop.driver.on_command(t_now, tuple(cmd))
        loop.sim.command(loop.driver.output(t_now))
        if tick % 20 == 0:
            f = loop.sim.gps_fix()
            e, n, u = loop.home.to_local(f.lat, f.lon, f.alt)
            loop.core.on_gps(LocalGps(e, n, u, f.ve, f.vn))
        if tick > 1200:
            heights.append(loop.sim.x[2])
    assert "take_off" in loop.core.planner.completed
    assert max(abs(h - 3.0) for h in heights) < 0.5
    assert np.hypot(loop.sim.x[0], loop.sim.x[1]) < 0.6
