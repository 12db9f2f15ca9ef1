"""A P+I(+D) controller with the seed-002 anti-windup and an injected clock.

The sampling period is measured between calls from the caller's clock (seed 002 §1.2.8: the time is read at
each call to the control library and the period is the difference), so a late step integrates the time that
really passed. The fields mirror one ``PID:`` group of a robot ``.conf`` (docs/dsp_protocol.md §4.1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from control.laws import AntiWindup, integrate_scalar


@dataclass(frozen=True)
class PidGains:
    """One ``PID:`` group: gains, initial integral, accumulator limits, default setpoint, feed-forward, output limits.

    ``th_dist`` and ``th_max`` are the two seed thresholds the ``.conf`` group has no field for.
    """

    kp: float
    ki: float = 0.0
    kd: float = 0.0
    integral: float = 0.0  # valor_int
    awu_max: float = math.inf  # max_awu
    awu_min: float = -math.inf  # min_awu
    reference: float = 0.0  # referencia
    offset: float = 0.0  # offset: the seed's sp_ω, the output at zero error
    sat_high: float = math.inf  # sat_encima
    sat_low: float = -math.inf  # sat_deb
    th_dist: float = math.inf
    th_max: float = math.inf

    def __post_init__(self) -> None:
        if not (self.awu_min <= self.awu_max and self.sat_low <= self.sat_high):
            raise ValueError(f"PID limits out of order: awu [{self.awu_min}, {self.awu_max}], "
                             f"sat [{self.sat_low}, {self.sat_high}]")

    @property
    def anti_windup(self) -> AntiWindup:
        return AntiWindup(th_dist=self.th_dist, th_max=self.th_max, accum_high=self.awu_max,
                          accum_low=self.awu_min)


class Pid:
    """``u = sat(offset + Kp·e + Ki·∫e + Kd·ė)`` with ``e = sp − x``; ``ė`` from ``rate`` when given (a measured
    derivative, e.g. a gyro, avoids differentiating noise), else from successive errors."""

    def __init__(self, gains: PidGains) -> None:
        self.gains = gains
        self.reset()

    def reset(self) -> None:
        """Back to the initial integral (valor_int); the next call only starts the clock."""
        self.integral = self.gains.integral
        self._last_time: float | None = None
        self._last_err = 0.0
        self.output = self.gains.offset

    def step(self, now: float, x: float, sp: float | None = None, rate: float | None = None) -> float:
        """Controller output at time ``now`` (s, the caller's clock) for measurement ``x``."""
        g = self.gains
        err = (g.reference if sp is None else sp) - x
        ts = None if self._last_time is None else now - self._last_time
        if ts is not None and ts <= 0:
            return self.output  # same instant (or a clock going back): nothing new to integrate
        if ts is not None:
            self.integral = integrate_scalar(self.integral, err, ts, g.th_dist, g.th_max, g.awu_min, g.awu_max)
        if rate is not None:
            d = rate
        else:
            d = 0.0 if ts is None else (err - self._last_err) / ts
        self._last_time, self._last_err = now, err
        u = g.offset + g.kp * err + g.ki * self.integral + g.kd * d
        self.output = min(max(u, g.sat_low), g.sat_high)
        return self.output
