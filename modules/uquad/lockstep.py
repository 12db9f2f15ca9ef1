"""The flight module's part in a lockstep simulation (``CROMAT_SIM``, docs/uquad.md §1.1, docs/simulation.md).

In lockstep the uQuad simulator is the robot's stepper: it runs ``step_s`` simulated seconds of frames (each IMU
frame waiting for the ESC set-point computed from it), then asks every bus member whether it has handled the step.
The flight module's bus loop is idle almost all the time; its work is done by its flight thread (the device
links) and its bus writer thread (the outbox). Its answer therefore carries:

- ``counts``: the bytes of the IMU and GPS links the flight thread has *finished* with (counted once the whole read
  is handled: estimator, law, command, the data queued for the bus), the commands it sent the motor driver, and
  the data and errors it has published. The simulator compares the first three with what it wrote and received on
  the same links (a byte or a set-point still travelling holds the step); the last two change between two rounds
  while something leaves the module, so the barrier's "two quiet rounds" sees it;
- ``busy``: data queued for the bus writer that it has not published yet.

The flight loop's time in lockstep is the frames' (10 ms each, ``clock = imu``): the simulator does not step
before the IMU link is connected and never loses a byte of it, so frame ``n`` is simulated time ``n × 10 ms``, and a
stamp is the simulation's epoch plus that (:func:`sim_epoch`). Pure apart from the counters' threads: tested in
``tests/modules/uquad/test_lockstep.py``.
"""

from __future__ import annotations

from bbcs.clock import Clock

FRAME_S = 0.01
"""Simulated seconds per IMU frame (the simulator's IMU_PERIOD)."""
IMU_KEY = "uquad_imu_rx"
"""Bytes of the IMU link the flight thread has finished with (since it connected)."""
GPS_KEY = "uquad_gps_rx"
"""Bytes of the GPS link the flight thread has finished with (since it connected)."""
MOTOR_KEY = "uquad_motor_tx"
"""Commands sent to the motor driver (one ESC set-point each, with the driver's ``--lockstep``)."""
PUBLISHED_KEY = "uquad_published"
ERRORS_KEY = "uquad_errors"


class FlightLedger:
    """What the flight thread has handled and what the bus writer has published, for the lockstep answer.

    Written by the flight thread (``handled``, ``sent``, ``queued``) and the writer (``published``), read by the
    bus loop when it answers; each is one integer, bumped after the work it counts is done."""

    def __init__(self) -> None:
        self.imu_rx = 0
        self.gps_rx = 0
        self.motor_tx: int | None = None
        """None: no motor driver link (``motor = sim``)."""
        self.queued = 0
        self.published = 0

    def busy(self) -> str:
        """'' once every datum queued for the bus has been published (or dropped: it will never be)."""
        waiting = self.queued - self.published
        return f"{waiting} data for the bus not yet published" if waiting > 0 else ""

    def counts(self, errors: int) -> dict[str, int]:
        counts = {IMU_KEY: self.imu_rx, GPS_KEY: self.gps_rx, PUBLISHED_KEY: self.published, ERRORS_KEY: errors}
        if self.motor_tx is not None:
            counts[MOTOR_KEY] = self.motor_tx
        return counts


def flight_time(frames: int) -> float:
    """Simulated seconds at the ``frames``-th IMU frame (the simulator sends its first at 10 ms)."""
    return frames * FRAME_S


def crossed(before: int, after: int, every: int) -> bool:
    """Whether a multiple of ``every`` frames lies in (before, after]: a datum due every ``every`` frames."""
    return after // every != before // every


def sim_epoch(clock: Clock) -> float | None:
    """The simulation's epoch (wall time of simulated 0) from a simulated clock that has been given the stepper's
    time, else None. Read so that a step applied between the two readings is never mixed into it."""
    step = getattr(clock, "step", -1)
    if not clock.simulated or step < 0:
        return None
    while True:
        t = clock.monotonic()
        stamp = clock.time()
        if clock.monotonic() == t:
            return stamp - t
