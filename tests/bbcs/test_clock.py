"""The one clock: the wall clock by default, simulated time moved only by the stepper's SimTime."""

from __future__ import annotations

import threading
import time

from bbcs.clock import WALL, Clock, SimClock, SimTime


def test_wall_clock_reads_the_host_clocks() -> None:
    assert isinstance(WALL, Clock) and not WALL.simulated
    assert abs(WALL.time() - time.time()) < 0.5
    assert abs(WALL.monotonic() - time.monotonic()) < 0.5


def test_sim_clock_reads_what_the_stepper_said_and_never_goes_back() -> None:
    clock = SimClock(epoch=1000.0)
    assert isinstance(clock, Clock) and clock.simulated
    assert (clock.monotonic(), clock.time(), clock.step) == (0.0, 1000.0, -1)
    assert clock.advance(SimTime(step=3, t=0.3, epoch=2000.0))
    assert (clock.monotonic(), clock.time(), clock.step) == (0.3, 2000.3, 3)
    assert not clock.advance(SimTime(step=2, t=0.2, epoch=2000.0))  # an older step changes nothing
    assert not clock.advance(SimTime(step=3, t=0.3, epoch=2000.0))
    assert clock.monotonic() == 0.3
    time.sleep(0.05)
    assert clock.monotonic() == 0.3  # the wall moving does not move simulated time


def test_sim_wait_lasts_simulated_seconds_however_long_the_wall_takes() -> None:
    clock = SimClock(epoch=0.0, poll_s=0.005)
    cond = threading.Condition()
    result: list[bool] = []

    def waiter() -> None:
        with cond:
            result.append(clock.wait_for(cond, lambda: False, 0.25))

    t = threading.Thread(target=waiter)
    t.start()
    time.sleep(0.1)  # 0.1 s of wall: still waiting, simulated time has not moved
    assert t.is_alive()
    clock.advance(SimTime(step=1, t=0.2, epoch=0.0))
    time.sleep(0.05)
    assert t.is_alive()  # 0.2 of 0.25 simulated seconds
    clock.advance(SimTime(step=2, t=0.3, epoch=0.0))
    t.join(2.0)
    assert result == [False]


def test_sim_wait_returns_as_soon_as_its_predicate_holds() -> None:
    clock = SimClock(epoch=0.0, poll_s=0.005)
    cond = threading.Condition()
    flag: list[int] = []

    def setter() -> None:
        time.sleep(0.05)
        with cond:
            flag.append(1)
            cond.notify_all()

    threading.Thread(target=setter).start()
    started = time.monotonic()
    with cond:
        assert clock.wait_for(cond, lambda: flag, 10.0)
    assert time.monotonic() - started < 2.0


def test_sim_sleep_ends_when_simulated_time_has_moved_on() -> None:
    clock = SimClock(epoch=0.0, poll_s=0.005)
    done = threading.Event()
    t = threading.Thread(target=lambda: (clock.sleep(1.0), done.set()))
    t.start()
    for step in range(1, 10):
        clock.advance(SimTime(step=step, t=step * 0.1, epoch=0.0))
        assert not done.wait(0.01)
    clock.advance(SimTime(step=10, t=1.0, epoch=0.0))
    assert done.wait(2.0)
