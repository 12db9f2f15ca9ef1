"""Robot state → Foxglove's well-known shapes (pure functions): map position, 3D pose, altitude/speed, lidar
points."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bbcs.geodesy import local_en


def local_enu(origin: tuple[float, float, float], point: tuple[float, float, float]) -> tuple[float, float, float]:
    """East, north, up metres of ``point`` from ``origin`` (lat, lon, alt) in the project's geodesy."""
    east, north = local_en(origin[0], origin[1], point[0], point[1])
    return east, north, point[2] - origin[2]


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
    """Altitude, ground speed, climb rate, heading and battery of a RobotTelemetry or GriState (as builtins)."""
    pos, vel = state.get("position"), state.get("velocity")
    if not pos:
        return None
    out: dict[str, Any] = {"altitude_m": pos["alt"], "ground_speed_mps": None, "climb_rate_mps": None,
                           "heading_deg": state.get("heading_deg"), "battery_v": state.get("battery_v")}
    if vel:
        out["ground_speed_mps"] = math.hypot(vel["vn"], vel["ve"])
        out["climb_rate_mps"] = -vel["vd"]
    return out


KINEMATICS_SCHEMA: dict[str, Any] = {
    "title": "cromat.Kinematics", "type": "object",
    "properties": {"altitude_m": {"type": "number"}, "ground_speed_mps": {"type": ["number", "null"]},
                   "climb_rate_mps": {"type": ["number", "null"]}, "heading_deg": {"type": ["number", "null"]},
                   "battery_v": {"type": ["number", "null"]}},
    "required": ["altitude_m"],
}


def zyx_quaternion(roll_deg: float, pitch_deg: float, yaw_deg: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the rotation Rz(yaw) · Ry(pitch) · Rx(roll), degrees (a lidar mounting in the body frame)."""
    r, p, y = math.radians(roll_deg) / 2, math.radians(pitch_deg) / 2, math.radians(yaw_deg) / 2
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy)


POINT_FIELDS = (("x", 0), ("y", 4), ("z", 8), ("layer", 12))
"""Float32 fields of one point in :func:`point_cloud_data`, with their byte offsets."""
POINT_STRIDE = 16


def point_cloud_data(xyz: np.ndarray, layer: np.ndarray) -> bytes:
    """Interleaved little-endian float32 x, y, z, layer per point: the ``data`` of a Foxglove PointCloud (the
    layer as a number the 3D panel can colour by)."""
    out = np.empty(len(xyz), dtype=[(name, "<f4") for name, _ in POINT_FIELDS])
    out["x"], out["y"], out["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    out["layer"] = layer
    return out.tobytes()
