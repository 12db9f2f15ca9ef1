"""The IMU library's raw-data queue and FIR filter (seed 002 §1.3, "Filtrado").

Raw frames, converted to floating point, go into a circular queue. Two things can be read from it: the newest
frame not yet used (:meth:`RawQueue.newest_unused`; when the main loop falls behind, older frames are never
"the newest", but they still count in the filter), or the FIR filter over the most recent frames
(:meth:`RawQueue.filtered`), the seed's equation 1.3 by default::

    y[n] = 0.2 x[n] + 0.2 x[n-1] + 0.2 x[n-2] + 0.2 x[n-3] + 0.1 x[n-4] + 0.1 x[n-5]

The coefficients make it an average, a pass-through (``[1]``), and so on. The seed switched the filter off in
flight (its delay hurt the control loop, and the Kalman filter already smooths), so the .conf's default
``IMU_FIR: []`` leaves it off; docs/uquad.md shows how to turn it on.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from modules.uquad.imu_protocol import ImuFrame

SEED_COEFFS = (0.2, 0.2, 0.2, 0.2, 0.1, 0.1)
"""Seed 002, equation 1.3: newest sample first."""
FIELDS = 11
"""acc xyz, gyro xyz, mag xyz, temperature ×10, pressure: the frame's measured values, in this order."""


def fir(history: np.ndarray, coeffs: Sequence[float]) -> np.ndarray:
    """``y = Σ_i coeffs[i] · x[n−i]`` over the rows of ``history`` (oldest first, newest last; at least
    ``len(coeffs)`` rows). Works on every column at once."""
    c = np.asarray(coeffs, dtype=float)
    if c.ndim != 1 or len(c) == 0:
        raise ValueError("a FIR filter needs at least one coefficient")
    if len(history) < len(c):
        raise ValueError(f"{len(c)} coefficients need {len(c)} samples, got {len(history)}")
    newest_first = np.asarray(history, dtype=float)[::-1][: len(c)]
    return c @ newest_first


def frame_values(frame: ImuFrame) -> np.ndarray:
    """A raw frame's measured values as floats (the queue's row)."""
    return np.array([*frame.acc, *frame.gyro, *frame.mag, frame.temp_x10, frame.pressure_pa], dtype=float)


def values_frame(values: np.ndarray, loop_us: int) -> ImuFrame:
    """A queue row (or a filtered one) back as a frame, for the same conversion as a raw frame."""
    v = [float(x) for x in values]
    return ImuFrame(loop_us, (v[0], v[1], v[2]), (v[3], v[4], v[5]), (v[6], v[7], v[8]),  # type: ignore[arg-type]
                    v[9], v[10])  # type: ignore[arg-type]


class RawQueue:
    """The circular queue of raw frames (``length`` must exceed the filter's coefficient count)."""

    def __init__(self, length: int, coeffs: Sequence[float] = SEED_COEFFS) -> None:
        if len(coeffs) == 0:
            raise ValueError("a FIR filter needs at least one coefficient")
        if length <= len(coeffs):
            raise ValueError(f"the raw queue ({length}) must be longer than the filter ({len(coeffs)} coefficients)")
        self.coeffs = tuple(float(c) for c in coeffs)
        self._rows = np.zeros((length, FIELDS))
        self._loop_us = [0] * length
        self._next = 0
        self.count = 0
        self._used = 0
        """How many frames had been pushed when the newest was last handed out."""

    def push(self, frame: ImuFrame) -> None:
        i = self._next
        self._rows[i] = frame_values(frame)
        self._loop_us[i] = frame.loop_us
        self._next = (i + 1) % len(self._rows)
        self.count += 1

    def _recent(self, n: int) -> np.ndarray:
        """The ``n`` most recent rows, oldest first."""
        idx = [(self._next - n + k) % len(self._rows) for k in range(n)]
        return self._rows[idx]

    def newest_unused(self) -> ImuFrame | None:
        """The newest frame, once; None when no frame arrived since the last call."""
        if self.count == 0 or self._used == self.count:
            return None
        self._used = self.count
        last = (self._next - 1) % len(self._rows)
        return values_frame(self._rows[last], self._loop_us[last])

    def filtered(self) -> ImuFrame | None:
        """The FIR filter over the most recent frames; None until the queue holds as many as the filter needs."""
        n = len(self.coeffs)
        if self.count < n:
            return None
        last = (self._next - 1) % len(self._rows)
        return values_frame(fir(self._recent(n), self.coeffs), self._loop_us[last])
