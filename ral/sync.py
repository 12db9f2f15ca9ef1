"""Fleet time: clock offsets between robots and the decisions of synchronised actions (docs/sync.md).

Pure, with every clock injected: the bus adapter (:mod:`ral.sync_bus`) feeds samples in and asks for decisions.

- :class:`OffsetEstimator`: NTP's four-timestamp exchange (t1 sent, t2 received by the peer, t3 answered by the
  peer, t4 answer received) per peer, over a sliding window; the estimate is the sample with the smallest
  round-trip delay (NTP's minimum-delay "clock filter"), whose error is bounded by half that delay.
- :class:`SkewedClock`: a robot's clock with an injected offset and drift, so tests give robots wrong clocks.
- :func:`plan_sync_start`: when, on this robot's own clock, a start agreed on the reference robot's clock is due.
- :func:`formation_goal` / :func:`formation_resend`: where a follower must be to keep its separation, and
  whether the leader moved enough to send it there again.

The fleet bench's measurement of this estimator on real Zenoh (``clock_offset_p99_ms``) is bench code, in
bench/clock_offset.py, so that the runtime package starts no routers.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from bbcs import geodesy
from bbcs.contracts.geo import GeoPoint

WINDOW = 8
"""Samples kept per peer (NTP's clock filter keeps 8)."""
MAX_AGE_S = 30.0
"""A sample older than this is not used (drift makes it stale)."""


@dataclass(frozen=True)
class ClockSample:
    """One exchange with a peer: t1/t4 on the own clock, t2/t3 on the peer's."""

    t1: float
    t2: float
    t3: float
    t4: float

    @property
    def offset(self) -> float:
        """peer clock − own clock, assuming a symmetric path."""
        return ((self.t2 - self.t1) + (self.t3 - self.t4)) / 2.0

    @property
    def delay(self) -> float:
        """Round trip minus the peer's own processing time."""
        return (self.t4 - self.t1) - (self.t3 - self.t2)


@dataclass(frozen=True)
class Estimate:
    offset_s: float
    delay_s: float
    samples: int
    taken_at: float
    """Own-clock time (t4) of the sample the estimate comes from."""


class OffsetEstimator:
    """Per-peer windows of :class:`ClockSample`; the estimate is the minimum-delay sample's offset."""

    def __init__(self, window: int = WINDOW, max_age_s: float = MAX_AGE_S) -> None:
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window}")
        self.window = window
        self.max_age_s = max_age_s
        self._samples: dict[str, deque[ClockSample]] = {}

    def add(self, peer: str, sample: ClockSample) -> bool:
        """Keep ``sample``; False (and nothing kept) when it cannot be a real exchange (negative delay)."""
        if not (math.isfinite(sample.offset) and math.isfinite(sample.delay)) or sample.delay < 0:
            return False
        self._samples.setdefault(peer, deque(maxlen=self.window)).append(sample)
        return True

    def forget(self, peer: str) -> None:
        self._samples.pop(peer, None)

    def peers(self) -> list[str]:
        return sorted(self._samples)

    def estimate(self, peer: str, now: float) -> Estimate | None:
        """The minimum-delay sample among the fresh ones (None: no fresh sample of ``peer``)."""
        fresh = [s for s in self._samples.get(peer, ()) if now - s.t4 <= self.max_age_s]
        if not fresh:
            return None
        best = min(fresh, key=lambda s: (s.delay, -s.t4))
        return Estimate(offset_s=best.offset, delay_s=best.delay, samples=len(fresh), taken_at=best.t4)


class SkewedClock:
    """``base() + offset_s + drift_ppm·1e-6·(base() − epoch)``: a robot clock that is wrong by a known amount."""

    def __init__(self, offset_s: float = 0.0, drift_ppm: float = 0.0,
                 base: Callable[[], float] = time.time) -> None:
        self.offset_s = offset_s
        self.drift_ppm = drift_ppm
        self.base = base
        self.epoch = base()

    def __call__(self) -> float:
        b = self.base()
        return b + self.offset_s + self.drift_ppm * 1e-6 * (b - self.epoch)

    def error_at(self, base_time: float) -> float:
        """How far this clock is from ``base`` at ``base_time`` (the truth tests compare estimates with)."""
        return self.offset_s + self.drift_ppm * 1e-6 * (base_time - self.epoch)


# ---------------------------------------------------------------- synchronised start


@dataclass(frozen=True)
class StartPlan:
    local_start: float
    """When this robot starts, on its own clock."""


@dataclass(frozen=True)
class StartRefused:
    reason: str


def plan_sync_start(*, robot: str, reference: str, start_at: float, own_now: float,
                    estimate: Estimate | None, min_lead_s: float = 0.2,
                    max_delay_s: float = 0.05, max_lead_s: float = 3600.0) -> StartPlan | StartRefused:
    """Where ``start_at`` (``reference``'s clock) falls on this robot's clock, or why the start is refused:
    no offset to the reference yet, an estimate too uncertain (round trip above ``max_delay_s``), an instant
    already past (less than ``min_lead_s`` ahead) or absurdly far."""
    if not math.isfinite(start_at):
        return StartRefused(f"start instant {start_at!r} is not a number")
    if robot == reference:
        offset = 0.0
    elif estimate is None:
        return StartRefused(f"no clock offset to the reference robot {reference!r} yet (is it on the mesh?)")
    elif estimate.delay_s > max_delay_s:
        return StartRefused(f"clock offset to {reference!r} too uncertain: best round trip "
                            f"{estimate.delay_s * 1000:.1f} ms > {max_delay_s * 1000:g} ms")
    else:
        offset = estimate.offset_s
    local = start_at - offset
    lead = local - own_now
    if lead < min_lead_s:
        return StartRefused(f"start instant is {-lead:.3f} s in the past on {reference!r}'s clock"
                            if lead < 0 else f"start instant only {lead:.3f} s ahead (need {min_lead_s:g} s)")
    if lead > max_lead_s:
        return StartRefused(f"start instant {lead:.0f} s ahead, more than {max_lead_s:g} s")
    return StartPlan(local_start=local)


# ---------------------------------------------------------------- formation


def offset_point(leader: GeoPoint, north_m: float, east_m: float, up_m: float) -> tuple[float, float, float]:
    """The point ``north_m``/``east_m``/``up_m`` from ``leader`` (local tangent plane: metres-accurate over the
    few hundred metres a formation spans)."""
    lat, lon = geodesy.offset(leader.lat, leader.lon, north_m, east_m)
    return lat, lon, leader.alt + up_m


def formation_goal(leader: GeoPoint, north_m: float, east_m: float, up_m: float) -> tuple[float, float, float]:
    """Where the follower must be: the leader's position plus the separation."""
    return offset_point(leader, north_m, east_m, up_m)


def formation_resend(last_goal: tuple[float, float, float] | None, goal: tuple[float, float, float],
                     last_sent_at: float | None, now: float, *, move_m: float = 3.0,
                     min_period_s: float = 1.0) -> bool:
    """Send the follower to ``goal`` again? Yes the first time, then when the goal moved more than ``move_m``
    and at most once per ``min_period_s`` (each send replaces the follower's path)."""
    if last_goal is None or last_sent_at is None:
        return True
    if now - last_sent_at < min_period_s:
        return False
    moved = geodesy.distance_m(last_goal[0], last_goal[1], goal[0], goal[1]) + abs(goal[2] - last_goal[2])
    return moved > move_m


def separation_error_m(follower: GeoPoint, leader: GeoPoint, north_m: float, east_m: float, up_m: float) -> float:
    """How far the follower is from where its separation puts it (the achieved formation error)."""
    lat, lon, alt = formation_goal(leader, north_m, east_m, up_m)
    return math.hypot(geodesy.distance_m(follower.lat, follower.lon, lat, lon), follower.alt - alt)
