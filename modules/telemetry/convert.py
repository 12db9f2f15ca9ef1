"""DSP telemetry → the robot-independent :class:`bbcs.contracts.robot.RobotTelemetry` (pure, no bus).

A field the DSP did not send (its telemetry mask) stays ``None``. A position outside WGS84 ranges (as the
:mod:`bbcs.contracts.geo` types declare them) or a non-finite number is not passed on: that field becomes ``None`` and
the caller counts it (no datum affected by an error is used).
"""

from __future__ import annotations

import math
from typing import TypeVar

import msgspec

from bbcs.contracts import dsp as p
from bbcs.contracts.geo import Attitude, GeoPoint, VelocityNED
from bbcs.contracts.robot import RobotTelemetry

_S = TypeVar("_S", bound=msgspec.Struct)


def mode_name(mode: int) -> str:
    try:
        return p.Mode(mode).name
    except ValueError:
        return f"UNKNOWN_{mode}"


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _part(part: msgspec.Struct | None, into: type[_S], name: str, dropped: list[str]) -> _S | None:
    """``part`` as the robot struct ``into`` (same field names), its ranges checked by ``into``'s type;
    None, with ``name`` added to ``dropped``, when a value is non-finite or out of range."""
    if part is None:
        return None
    values = msgspec.structs.asdict(part)
    if _finite(*values.values()):
        try:
            return msgspec.convert(values, into)
        except msgspec.ValidationError:
            pass
    dropped.append(name)
    return None


def to_robot_telemetry(t: p.Telemetry, stamp: float) -> tuple[RobotTelemetry, list[str]]:
    """The robot telemetry of one DSP frame, and the names of fields dropped as invalid."""
    dropped: list[str] = []
    position = _part(t.position, GeoPoint, "position", dropped)
    attitude = _part(t.attitude, Attitude, "attitude", dropped)
    velocity = _part(t.velocity, VelocityNED, "velocity", dropped)
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
    if t.engine is not None:
        if _finite(t.engine.battery_v) and 0.0 <= t.engine.battery_v <= 100.0:
            fields["battery_v"] = t.engine.battery_v
        else:
            dropped.append("battery")
    out = RobotTelemetry(
        stamp=stamp, position=position, attitude=attitude, velocity=velocity, heading_deg=heading, **fields
    )  # type: ignore[arg-type]
    return out, dropped
