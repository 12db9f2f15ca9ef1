"""Robot-independent structs that many processes share: the generic robot telemetry.

A robot's telemetry module turns its own device data (for the UAV: the DSP's telemetry) into
:class:`RobotTelemetry`, published on an unsafe state slot; the Module Manager folds it into the robot state
and the RAL serves it to ground stations. Nothing here is UAV-specific: a field a robot lacks stays ``None``.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from bbcs.contracts.geo import Attitude, GeoPoint, VelocityNED


class RobotTelemetry(msgspec.Struct, frozen=True, kw_only=True):
    """What every robot reports about its body; ``None`` when the robot does not know it (yet)."""

    stamp: float
    """Seconds since the epoch at which the telemetry module produced it."""
    position: GeoPoint | None = None
    attitude: Attitude | None = None
    velocity: VelocityNED | None = None
    heading_deg: float | None = None
    mode: int | None = None
    """The low-level controller's operating mode (robot-specific meaning, documented by the robot)."""
    mode_name: str = ""
    tracking: bool | None = None
    path_valid: bool | None = None
    airborne: bool | None = None
    waypoints_queued: int | None = None
    pan_deg: float | None = None
    tilt_deg: float | None = None
    pan_tilt_mode: int | None = None
    error_code: int | None = None
    """Error code the low-level controller reports (0 none)."""
    battery_v: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] | None = None
    """Battery voltage (V) as the robot measures it (the UAV: the DSP's ``Engine.battery_v``)."""
