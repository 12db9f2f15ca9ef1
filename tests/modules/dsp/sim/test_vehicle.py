"""The point-mass helicopter: limits hold, the ground holds, attitude follows acceleration."""

from __future__ import annotations

import numpy as np
import pytest

from modules.dsp.sim.vehicle import ROTOR_FLIGHT_RPM, Vehicle, VehicleParams, VehicleState, wrap_deg

DT = 0.02


def flying(**params: float) -> Vehicle:
    state = VehicleState(pos=np.array([0.0, 0.0, 20.0]), rotor_rpm=ROTOR_FLIGHT_RPM)
    return Vehicle(VehicleParams(**params), state)


def test_speed_climb_and_acceleration_limits() -> None:
    v = flying(max_speed=5.0, max_climb=1.5, max_accel=2.0)
    prev = v.state.vel.copy()
    for _ in range(500):
        v.step(DT, np.array([50.0, 50.0, 10.0]), 0.0, ROTOR_FLIGHT_RPM)
        acc = (v.state.vel - prev) / DT
        assert np.hypot(acc[0], acc[1]) <= 2.0 + 1e-9
        prev = v.state.vel.copy()
    assert v.state.ground_speed == pytest.approx(5.0, abs=1e-3)
    assert v.state.vel[2] == pytest.approx(1.5, abs=1e-3)


def test_ground_stops_descent_and_needs_rotor_to_lift() -> None:
    v = Vehicle()
    for _ in range(100):
        v.step(DT, np.array([3.0, 0.0, 1.0]), 0.0, 0.0)
    assert v.state.pos.tolist() == [0.0, 0.0, 0.0]  # no rotor, no lift, no sliding
    for _ in range(300):
        v.step(DT, np.array([0.0, 0.0, 1.0]), 0.0, ROTOR_FLIGHT_RPM)
    assert v.state.airborne
    for _ in range(3000):
        v.step(DT, np.array([0.0, 0.0, -2.0]), 0.0, ROTOR_FLIGHT_RPM)
    assert v.state.pos[2] == 0.0 and v.state.vel[2] == 0.0 and not v.state.airborne


def test_heading_turns_at_a_bounded_rate_the_short_way() -> None:
    v = flying(max_yaw_rate=30.0)
    v.state.heading = 170.0
    v.step(DT, np.zeros(3), -170.0, ROTOR_FLIGHT_RPM)  # 20° to the right across ±180
    assert v.state.heading == pytest.approx(170.0 + 30.0 * DT)
    for _ in range(200):
        v.step(DT, np.zeros(3), -170.0, ROTOR_FLIGHT_RPM)
    assert v.state.heading == pytest.approx(-170.0, abs=0.01)


def test_attitude_tilts_into_acceleration() -> None:
    v = flying()
    v.step(DT, np.array([10.0, 0.0, 0.0]), 0.0, ROTOR_FLIGHT_RPM)  # accelerate north, nose north
    assert v.state.pitch < -5.0 and abs(v.state.roll) < 1e-9
    v = flying()
    v.step(DT, np.array([0.0, 10.0, 0.0]), 0.0, ROTOR_FLIGHT_RPM)  # accelerate east: roll right
    assert v.state.roll > 5.0


def test_bad_time_step_is_refused() -> None:
    with pytest.raises(ValueError):
        Vehicle().step(0.0, np.zeros(3), 0.0, 0.0)


@pytest.mark.parametrize(("angle", "wrapped"), [(0, 0), (180, -180), (-180, -180), (190, -170), (-190, 170),
                                                (540, -180), (-180.5, 179.5), (-1e-300, 0)])
def test_wrap_deg(angle: float, wrapped: float) -> None:
    got = wrap_deg(angle)
    assert -180.0 <= got < 180.0
    assert got == pytest.approx(wrapped, abs=1e-9)
