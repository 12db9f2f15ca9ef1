"""Aircraft pose and gimbal angles as the vision module receives them (degrees, metres).

Plain frozen dataclasses, validated on construction, so that a bad telemetry value is a clear error here and
never reaches the geometry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .geodesy import check_lla


def _finite(name: str, value: float) -> None:
    if not math.isfinite(value):
        raise ValueError(f"{name} {value!r} is not finite")


@dataclass(frozen=True, slots=True)
class AircraftPose:
    """Position (WGS84 lat/lon in degrees, altitude in metres) and attitude in degrees.

    Attitude is aerospace ZYX: ``yaw`` (heading, clockwise from north), then ``pitch`` (nose up positive),
    then ``roll`` (right wing down positive), rotating NED into the body frame (x forward, y right, z down).
    """

    lat: float
    lon: float
    alt: float
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0

    def __post_init__(self) -> None:
        check_lla(self.lat, self.lon, self.alt)
        for name in ("roll", "pitch", "yaw"):
            _finite(name, getattr(self, name))
        if not -90.0 <= self.pitch <= 90.0:
            raise ValueError(f"pitch {self.pitch!r} outside [-90, 90]")


@dataclass(frozen=True, slots=True)
class Gimbal:
    """Pan & tilt angles in degrees, with the DATOS_PT ranges.

    ``pan`` turns the camera about the mount's z (down) axis, positive to the right (clockwise seen from
    above), 0 = straight ahead. ``tilt`` is the elevation of the optical axis above the mount's x-y plane:
    0 = level, -90 = straight down (nadir), positive = looking up. The mount is the airframe or, for a
    stabilised unit, the heading-and-horizon frame (``geometry`` module docstring).
    """

    pan: float
    tilt: float

    def __post_init__(self) -> None:
        _finite("pan", self.pan)
        _finite("tilt", self.tilt)
        if not -180.0 <= self.pan <= 180.0:
            raise ValueError(f"pan {self.pan!r} outside [-180, 180]")
        if not -90.0 <= self.tilt <= 90.0:
            raise ValueError(f"tilt {self.tilt!r} outside [-90, 90]")
