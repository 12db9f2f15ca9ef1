"""Robot state → Foxglove's well-known shapes (pure functions): map position, 3D pose, altitude/speed."""

from __future__ import annotations

import math
from typing import Any

EARTH_RADIUS_M = 6_371_000.0


def local_enu(origin: tuple[float, float, float], point: tuple[float, float, float]) -> tuple[float, float, float]:
    """East, north, up metres of ``point`` from ``origin`` (lat, lon, alt); flat earth, fine over kilometres."""
    lat0, lon0, alt0 = origin
    lat, lon, alt = point
    east = math.radians(lon - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
    north = math.radians(lat - lat0) * EARTH_RADIUS_M
    return east, north, alt - alt0


def enu_quaternion(roll_deg: float, pitch_deg: float, yaw_deg: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a body (x forward, y left, z up) in an east-north-up world, from aviation angles
    (roll right-wing-down, pitch nose-up, yaw clockwise from north, degrees)."""
    r = math.radians(roll_deg)
    p = -math.radians(pitch_deg)  # nose-up is a negative rotation about the body's left axis
    y = math.radians(90.0 - yaw_deg)  # clockwise from north → counter-clockwise from east
    cr, sr = math.cos(r / 2), math.sin(r / 2)
    cp, sp = math.cos(p / 2), math.sin(p / 2)
    cy, sy = math.cos(y / 2), math.sin(y / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy)


def kinematics(state: dict[str, Any]) -> dict[str, Any] | None:
    """Altitude, ground speed, climb rate and heading of a RobotTelemetry or GriState (as builtins)."""
    pos, vel = state.get("position"), state.get("velocity")
    if not pos:
        return None
    out: dict[str, Any] = {"altitude_m": pos["alt"], "ground_speed_mps": None, "climb_rate_mps": None,
                           "heading_deg": state.get("heading_deg")}
    if vel:
        out["ground_speed_mps"] = math.hypot(vel["vn"], vel["ve"])
        out["climb_rate_mps"] = -vel["vd"]
    return out


KINEMATICS_SCHEMA: dict[str, Any] = {
    "title": "cromat.Kinematics", "type": "object",
    "properties": {"altitude_m": {"type": "number"}, "ground_speed_mps": {"type": ["number", "null"]},
                   "climb_rate_mps": {"type": ["number", "null"]}, "heading_deg": {"type": ["number", "null"]}},
    "required": ["altitude_m"],
}
