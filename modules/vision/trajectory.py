"""A short waypoint list from the aircraft toward and over the target, for the path follower's DATOS stream.

Waypoints are spaced evenly along the ground track from the aircraft to the target; the last one (or the
only one, when the aircraft is already within ``arrive_radius_m``) is over the target. With ``overfly_m`` > 0
one more waypoint continues past the target along the same track. The altitude of every waypoint is
max(aircraft altitude, target altitude + ``min_height_m``): the path never descends below the current height
and keeps a clearance above the target. Heading is not part of a waypoint (SPEC §3.3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .geodesy import LocalFrame, check_lla
from .pose import AircraftPose


@dataclass(frozen=True)
class TrajectoryConfig:
    n_points: int = 3
    min_height_m: float = 20.0
    overfly_m: float = 0.0
    arrive_radius_m: float = 2.0

    def __post_init__(self) -> None:
        if not 1 <= self.n_points <= 100:
            raise ValueError(f"n_points {self.n_points} outside [1, 100]")
        for name in ("min_height_m", "overfly_m", "arrive_radius_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} {value!r} must be finite and >= 0")


def plan_trajectory(
    aircraft: AircraftPose, target_lla: tuple[float, float, float], config: TrajectoryConfig
) -> NDArray[np.float64]:
    """Waypoints (n, 3) of (lat, lon, alt), lat in [-90, 90], lon in [-180, 180), toward the target."""
    check_lla(*target_lla)
    frame = LocalFrame(aircraft.lat, aircraft.lon, 0.0)
    target = frame.to_enu(*target_lla)
    start = np.array([0.0, 0.0])
    track = target[:2] - start
    distance = float(np.hypot(*track))
    altitude = max(aircraft.alt, target_lla[2] + config.min_height_m)
    if distance <= config.arrive_radius_m:
        ground = target[None, :2]
    else:
        fractions = np.arange(1, config.n_points + 1) / config.n_points
        ground = start + fractions[:, None] * track
    if config.overfly_m > 0.0 and distance > 0.0:
        ground = np.vstack((ground, target[:2] + track / distance * config.overfly_m))
    enu = np.column_stack((ground, np.full(len(ground), altitude)))
    return frame.to_lla(enu)
