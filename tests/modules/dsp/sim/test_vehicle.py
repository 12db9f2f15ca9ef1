"""The helicopter model flown by the DSP's loops: limits hold, the ground holds, attitude follows acceleration."""

from __future__ import annotations

import numpy as np
import pytest

from bbcs.contracts.dsp import Axis
from modules.dsp.sim.vehicle import ROTOR_FLIGHT_RPM, Vehicle, VehicleParams, VehicleState, wrap_deg

DT = 0.02


def flying(**params: float) -> Vehicle:
    state = VehicleState(pos=np.array([0.0, 0.0, 20.0]), rotor_rpm=ROTOR_FLIGHT_RPM)
    return Vehicle(VehicleParams(**params), state)


def test_speed_and_climb_limits() -> None:
    v = flying(max_speed=5.0, max_climb=1.5)
    speeds, climbs = [], []
    for _ in range(750):
        v.step(DT, np.array([50.0, 50.0, 10.0]), 45.0, ROTOR_FLIGHT_RPM)
        speeds.append(v.state.ground_speed)
        climbs.append(v.state.vel[2])
    assert max(speeds) <= 5.0 + 1e-9 and max(climbs) <= 1.5 + 1e-9
    assert speeds[-1] == pytest.approx(5.0, abs=0.05)  # reaches the limit, does not crawl below it
    assert climbs[-1] == pytest.approx(1.5, abs=0.05)


def test_ground_stops_descent_and_needs_rotor_to_lift() -> None:
    v = Vehicle()
    for _ in range(100):
        v.step(DT, np.array([3.0, 0.0, 1.0]), 0.0, 0.0)
    assert v.state.pos.tolist() == [0.0, 0.0, 0.0]  # no rotor, no lift, no sliding
    for _ in range(400):
        v.step(DT, np.array([0.0, 0.0, 1.0]), 0.0, ROTOR_FLIGHT_RPM)
    assert v.state.airborne
    for _ in range(3000):
        v.step(DT, np.array([0.0, 0.0, -2.0]), 0.0, ROTOR_FLIGHT_RPM)
    assert v.state.pos[2] == 0.0 and v.state.vel[2] == 0.0 and not v.state.airborne


def test_heading_turns_at_a_bounded_rate_the_short_way() -> None:
    v = flying(max_yaw_rate=30.0)
    v.state.heading = 170.0
    v = Vehicle(v.params, v.state)
    headings = []
    for _ in range(400):
        v.step(DT, np.zeros(3), -170.0, ROTOR_FLIGHT_RPM)  # 20° to the right across ±180
        headings.append(v.state.heading)
    assert all(abs(h) > 150.0 for h in headings)  # never the long way round through 0
    assert v.state.heading == pytest.approx(-170.0, abs=0.5)
    assert max(abs(np.diff(np.unwrap(np.radians(headings))))) / DT <= np.radians(30.0) * 1.3


def test_attitude_tilts_into_acceleration() -> None:
    v = flying()
    for _ in range(25):
        v.step(DT, np.array([10.0, 0.0, 0.0]), 0.0, ROTOR_FLIGHT_RPM)  # accelerate north, nose north
    assert v.state.pitch < -5.0 and abs(v.state.roll) < 0.5
    v = flying()
    for _ in range(25):
        v.step(DT, np.array([0.0, 10.0, 0.0]), 0.0, ROTOR_FLIGHT_RPM)  # accelerate east: roll right
    assert v.state.roll > 5.0


def test_loops_measure_their_period_from_the_vehicles_clock() -> None:
    v = flying(control_dt=0.01)
    v.step(0.05, np.zeros(3), 0.0, ROTOR_FLIGHT_RPM)  # five 10 ms sub-steps
    assert v.time_s == pytest.approx(0.05)
    assert v.pids[Axis.ROLL]._last_time == pytest.approx(0.05)


def test_wind_is_seeded_and_pushes_downwind() -> None:
    def hover(seed: int) -> np.ndarray:
        v = flying(wind_north=3.0, gust_std=0.5, seed=seed)
        track = []
        for _ in range(300):
            v.step(DT, np.zeros(3), 0.0, ROTOR_FLIGHT_RPM)
            track.append(v.state.pos.copy())
        return np.array(track)

    a, b, c = hover(1), hover(1), hover(2)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert a[-1, 0] > 0.5  # a wind toward north moves a hovering aircraft that nothing guides north


def test_bad_time_step_is_refused() -> None:
    with pytest.raises(ValueError):
        Vehicle().step(0.0, np.zeros(3), 0.0, 0.0)


@pytest.mark.parametrize(("angle", "wrapped"), [(0, 0), (180, -180), (-180, -180), (190, -170), (-190, 170),
                                                (540, -180), (-180.5, 179.5), (-1e-300, 0)])
def test_wrap_deg(angle: float, wrapped: float) -> None:
    got = wrap_deg(angle)
    assert -180.0 <= got < 180.0
    assert got == pytest.approx(wrapped, abs=1e-9)
