"""The uQuad simulator as the robot's lockstep stepper (``CROMAT_SIM``; docs/uquad.md §1.1, docs/simulation.md).

Each step is ``step_s`` simulated seconds of 10 ms IMU frames, each frame still waiting for the ESC set-point
computed from it (the device links' lockstep); then the simulator publishes the simulated time and asks the bus
barrier, and steps on only once every member has handled the step **and** nothing is still on the device links:

- the flight module has finished with every IMU and GPS byte written to it on the current connection (its answer's
  ``counts``, modules/uquad/lockstep.py), as the DSP simulator counts its line;
- every command the flight module sent the motor driver has arrived here as an ESC set-point (the driver's
  ``--lockstep`` forwards one per command). After the driver or the flight module restarts (a new ESC connection,
  or the module's count going back), the ESC link is counted from the first barrier after it: what was in flight
  at that instant is not seen;
- no step is taken before the IMU link has had a reader (the flight module connects while the robot starts): the
  flight loop's time is its frame count, which is simulated time only if it gets the first frame.

The decisions here are pure (no sockets, no clock): :class:`LinkCheck` is the barrier's ``check``,
:func:`lockstep_speed` and :func:`frames_per_step` the pace. Tested in ``tests/modules/uquad/sim/test_lockstep.py``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

from bbcs.lockstep import Done
from modules.uquad.lockstep import FRAME_S, GPS_KEY, IMU_KEY, MOTOR_KEY


def lockstep_speed(speed: float | Literal["max"] | None, own_speed: float) -> float | None:
    """Simulated seconds per wall second at most (None: as fast as every member allows): the launch's ``speed``
    (``[sim] speed``, ``cromat launch --speed``), else the simulator's own ``--speed``."""
    if speed == "max":
        return None
    return own_speed if speed is None else float(speed)


def frames_per_step(step_s: float) -> int:
    """IMU frames (10 ms each) in one barrier step of ``step_s`` simulated seconds (at least one)."""
    return max(1, round(step_s / FRAME_S))


def next_step_at(previous: float, started: float, step_wall: float | None) -> float:
    """When (wall) the step after one that ``started`` may start: ``step_wall`` after the later of its start and
    when it was due (``previous``): a step late on the wall is not made up by a burst. None: at once."""
    if step_wall is None:
        return started
    return max(previous, started) + step_wall


@dataclass
class DeviceLinks:
    """The simulator's end of the device links as the check counts them (each since its current connection)."""

    imu_tx: int = 0
    """Bytes written to the IMU link's current reader."""
    imu_readers: int = 0
    """Connections the IMU link has had (0: the flight module has not connected yet)."""
    gps_tx: int = 0
    esc_rx: int = 0
    """ESC set-points received on the current ESC connection."""
    esc_connection: int = 0
    """Which ESC connection (counted from 1; 0: none yet)."""
    esc_connected: bool = False


@dataclass
class LinkCheck:
    """The barrier's check of the device links: '' when nothing is on them, else what is."""

    _esc_offset: int = 0
    _esc_connection: int = 0
    _sent: int = 0

    def __call__(self, answers: Mapping[str, Done], links: DeviceLinks) -> str:
        if links.imu_readers == 0:
            return "the IMU link has had no reader yet (the flight module is starting)"
        for done in answers.values():
            counts = done.counts
            imu, gps, sent = counts.get(IMU_KEY), counts.get(GPS_KEY), counts.get(MOTOR_KEY)
            if imu is not None and imu != links.imu_tx:
                return f"IMU link: {done.member} has handled {imu} B of the {links.imu_tx} B written"
            if gps is not None and gps != links.gps_tx:
                return f"GPS link: {done.member} has handled {gps} B of the {links.gps_tx} B written"
            if sent is not None:
                why = self._esc(done.member, sent, links)
                if why:
                    return why
        return ""

    def _esc(self, member: str, sent: int, links: DeviceLinks) -> str:
        if not links.esc_connected:
            if links.esc_connection == 0 and sent > 0:  # the driver connects at its first set-point
                return f"ESC link: {member} sent {sent} commands, the driver has not connected yet"
            return ""  # the driver gone: nothing can arrive (a restarted one is counted from its connection)
        restarted = (self._esc_connection not in (0, links.esc_connection)) or sent < self._sent
        if restarted:
            self._esc_offset = sent - links.esc_rx
        self._esc_connection, self._sent = links.esc_connection, sent
        missing = sent - self._esc_offset - links.esc_rx
        return f"ESC link: {missing} of {member}'s commands not arrived as set-points" if missing else ""
