"""The flight module's lockstep answer (modules/uquad/lockstep.py): what its threads have handled and published,
its frames' time and the simulation's epoch read from a simulated clock."""

from __future__ import annotations

import threading

from bbcs.clock import WALL, SimClock, SimTime
from modules.uquad.lockstep import (
    ERRORS_KEY,
    GPS_KEY,
    IMU_KEY,
    MOTOR_KEY,
    PUBLISHED_KEY,
    FlightLedger,
    crossed,
    flight_time,
    sim_epoch,
)


def test_the_ledger_is_busy_while_queued_data_are_not_published():
    ledger = FlightLedger()
    assert ledger.busy() == ""
    ledger.queued += 3
    assert ledger.busy() == "3 data for the bus not yet published"
    ledger.published += 2
    assert ledger.busy() == "1 data for the bus not yet published"
    ledger.published += 1
    assert ledger.busy() == ""


def test_the_counts_carry_the_links_and_what_left_the_module():
    ledger = FlightLedger()
    ledger.imu_rx, ledger.gps_rx, ledger.published = 28 * 20, 70, 51
    assert ledger.counts(errors=2) == {IMU_KEY: 560, GPS_KEY: 70, PUBLISHED_KEY: 51, ERRORS_KEY: 2}
    ledger.motor_tx = 19  # a motor driver link: its commands are counted too
    assert ledger.counts(errors=2)[MOTOR_KEY] == 19


def test_frames_are_simulated_time_and_a_period_in_frames_is_met_once_per_multiple():
    assert flight_time(0) == 0.0 and flight_time(1) == 0.01 and abs(flight_time(512) - 5.12) < 1e-12
    assert [n for n in range(1, 41) if crossed(n - 1, n, 10)] == [10, 20, 30, 40]
    assert crossed(8, 12, 10) and not crossed(10, 19, 10) and crossed(19, 20, 10)
    # floats would miss some: 30 frames of 0.01 s are not 0.1 + 0.1 + 0.1
    assert flight_time(30) < 0.1 + 0.1 + 0.1


def test_the_epoch_comes_only_from_a_clock_given_the_steppers_time():
    assert sim_epoch(WALL) is None
    clock = SimClock(epoch=5.0)
    assert sim_epoch(clock) is None  # not yet given the stepper's time: its own epoch is no simulation's
    clock.advance(SimTime(step=0, t=0.0, epoch=1000.0))
    assert sim_epoch(clock) == 1000.0
    clock.advance(SimTime(step=7, t=1.4, epoch=1000.0))
    assert sim_epoch(clock) == 1000.0


def test_the_epoch_is_never_mixed_with_a_step_applied_while_it_is_read():
    clock = SimClock()
    clock.advance(SimTime(step=0, t=0.0, epoch=2000.0))
    stop = threading.Event()

    def stepper() -> None:
        step = 0
        while not stop.is_set():
            step += 1
            clock.advance(SimTime(step=step, t=step * 0.2, epoch=2000.0))

    thread = threading.Thread(target=stepper)
    thread.start()
    try:
        epochs = {sim_epoch(clock) for _ in range(20000)}
    finally:
        stop.set()
        thread.join()
    assert all(abs(e - 2000.0) < 1e-9 for e in epochs), epochs  # a mixed reading would be a step (0.2 s) off
