"""Geographic, angle and speed types, declared once with their ranges (so decoding a struct is validating it).

Every struct that carries a position or an angle uses these aliases; a range changes here and nowhere else.
Angles are degrees unless the alias says radians. Latitude/longitude are WGS84.
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec

Latitude = Annotated[float, msgspec.Meta(ge=-90.0, le=90.0, description="degrees north (WGS84)")]
"""WGS84 latitude, degrees, [-90, 90]."""
Longitude = Annotated[float, msgspec.Meta(ge=-180.0, le=180.0, description="degrees east (WGS84)")]
"""WGS84 longitude, degrees, [-180, 180]."""

AltitudeAMSL = Annotated[float, msgspec.Meta(ge=-500.0, le=10_000.0, description="metres above mean sea level")]
"""Metres above mean sea level: the DSP's reference for waypoints and telemetry positions (GPS altitude). A sanity
range for a robot's points, not a flight envelope (the RAL checks the robot's own limits)."""
HeightAboveHome = Annotated[float, msgspec.Meta(ge=1.0, le=500.0, description="metres above the take-off point")]
"""Metres above the take-off point (home)."""
SensorAltitudeEllipsoid = Annotated[float, msgspec.Meta(ge=-10_000.0, le=100_000.0)]
"""Metres above the WGS84 ellipsoid as an INS may report it (wider than a commanded point: a sensor's range)."""

DegreesSigned180 = Annotated[float, msgspec.Meta(ge=-180.0, le=180.0, description="degrees")]
"""Degrees, [-180, 180]: pan, roll, yaw as sensors report them."""
DegreesSigned90 = Annotated[float, msgspec.Meta(ge=-90.0, le=90.0, description="degrees")]
"""Degrees, [-90, 90]: tilt, pitch."""
HeadingDegrees = Annotated[float, msgspec.Meta(ge=-180.0, lt=180.0)]
"""Heading, degrees, [-180, 180), 0 = north, clockwise."""
Radians = Annotated[float, msgspec.Meta(ge=-math.pi, lt=math.pi)]
"""An angle in radians, [-π, π)."""

MAX_SPEED_LIMIT = 30.0
"""m/s: the DSP protocol's ceiling on a commanded speed; each airframe's MAX_SPEED (its .conf) is lower and is
checked where the robot's limits are known (the RAL's admission, the path follower)."""
CommandSpeed = Annotated[float, msgspec.Meta(ge=0.0, le=MAX_SPEED_LIMIT, description="m/s")]
"""A commanded speed, m/s, [0, MAX_SPEED_LIMIT]: a task's, the SPEED_SEG_CAM slot's, the DSP's SET_SPEED (0 stops)."""
RotorRpm = Annotated[float, msgspec.Meta(ge=0.0, le=1800.0, description="rotor rpm")]
"""The bridge's rotor reference (REFS_SEG_CAM ``ref_rpm_motor``), rpm."""


class Vertex(msgspec.Struct, frozen=True, kw_only=True):
    """A horizontal position, WGS84 degrees: a polygon corner, a point of a planned path, a circle's centre."""

    lat: Latitude
    lon: Longitude


class GeoPoint(msgspec.Struct, frozen=True, kw_only=True):
    """WGS84 degrees, altitude in metres above the ellipsoid (unbounded: whatever the robot measured)."""

    lat: Latitude
    lon: Longitude
    alt: float


class Attitude(msgspec.Struct, frozen=True, kw_only=True):
    """Degrees: roll, pitch, yaw (yaw 0 = north, clockwise)."""

    roll: float
    pitch: float
    yaw: float


class VelocityNED(msgspec.Struct, frozen=True, kw_only=True):
    """Metres per second, north-east-down."""

    vn: float
    ve: float
    vd: float
