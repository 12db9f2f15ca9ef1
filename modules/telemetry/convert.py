"""DSP telemetry → the robot-independent :class:`bbcs.robot.RobotTelemetry` (pure, no bus).

A field the DSP did not send (its telemetry mask) stays ``None``. A position outside WGS84 ranges or a
non-finite number is not passed on: that field becomes ``None`` and the caller counts it (no datum affected by
an error is used).
"""

from __future__ import annotations

import math

from bbcs.robot import Attitude, GeoPoint, RobotTelemetry, VelocityNED
from modules.dsp import protocol as p


def mode_name(mode: int) -> str:
    try:
        return p.Mode(mode).name
    except ValueError:
        return f"UNKNOWN_{mode}"


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def to_robot_telemetry(t: p.Telemetry, stamp: float) -> tuple[RobotTelemetry, list[str]]:
    """The robot telemetry of one DSP frame, and the names of fields dropped as invalid."""
    dropped: list[str] = []
    position = None
    if t.position is not None:
        pos = t.position
        if _finite(pos.lat, pos.lon, pos.alt) and -90 <= pos.lat <= 90 and -180 <= pos.lon <= 180:
            position = GeoPoint(lat=pos.lat, lon=pos.lon, alt=pos.alt)
        else:
            dropped.append("position")
    attitude = None
    if t.attitude is not None:
        a = t.attitude
        if _finite(a.roll, a.pitch, a.yaw):
            attitude = Attitude(roll=a.roll, pitch=a.pitch, yaw=a.yaw)
        else:
            dropped.append("attitude")
    velocity = None
    if t.velocity is not None:
        v = t.velocity
        if _finite(v.vn, v.ve, v.vd):
            velocity = VelocityNED(vn=v.vn, ve=v.ve, vd=v.vd)
        else:
            dropped.append("velocity")
    heading = None
    if t.heading is not None:
        if _finite(t.heading):
            heading = t.heading
        else:
            dropped.append("heading")
    fields: dict[str, object] = {}
    if t.status is not None:
        s = t.status
        fields.update(
            mode=s.mode,
            mode_name=mode_name(s.mode),
            tracking=s.tracking,
            path_valid=s.path_valid,
            airborne=s.airborne,
            waypoints_queued=s.queue_length,
        )
    if t.pan_tilt is not None:
        pt = t.pan_tilt
        if _finite(pt.pan, pt.tilt):
            fields.update(pan_deg=pt.pan, tilt_deg=pt.tilt, pan_tilt_mode=pt.mode)
        else:
            dropped.append("pan_tilt")
    if t.error_code is not None:
        fields["error_code"] = t.error_code
    out = RobotTelemetry(
        stamp=stamp, position=position, attitude=attitude, velocity=velocity, heading_deg=heading, **fields
    )  # type: ignore[arg-type]
    return out, dropped
