"""The uQuad simulator's truth as the monitor's :class:`VehicleTruth` (pure: a line in, a truth out).

The uQuad simulator (``python -m modules.uquad.sim --truth 127.0.0.1:PORT``, modules/uquad/sim/server.py) serves
its true state as JSON lines on a TCP port: ``t`` (its simulated seconds; in lockstep it is the robot's stepper, so
``t`` is the robot clock's ``t``, as the DSP simulator's ``time_s`` is), ``x`` (the model's 12 states: x y z east,
north, up metres from the .conf's home, then ψ φ θ roll about x, pitch about y, yaw about z, radians, then vx vy vz
m/s, then p q r) and ``on_ground``. The monitor judges a :class:`VehicleTruth` (degrees on the geodesy the rest of
the robot uses, velocity north-east-up, aerospace attitude: roll right side down, pitch nose up, heading clockwise
from north), so the line is converted here.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from bbcs.contracts.vehicle_truth import VehicleTruth
from bbcs.geodesy import LocalFrame

STATES = 12
UQUAD_TRUTH_PERIOD_S = 0.05
"""The simulator writes a truth line once its time reaches the next 0.05 s (``truth_period``), at an IMU frame
(0.01 s): not necessarily at a step's end (the sum of its periods drifts an ulp past it, and the line comes a
frame later, in the next step)."""


class BadTruthLine(ValueError):
    """A truth line the monitor cannot use (not JSON, no ``t`` or ``x``, a value out of range)."""


def _wrap180(deg: float) -> float:
    return (deg + 180.0) % 360.0 - 180.0


def aerospace_attitude(roll_rad: float, pitch_rad: float, yaw_rad: float) -> tuple[float, float, float]:
    """The model's Euler angles (body x forward, y left, z up in an east-north-up world; R = Rz·Ry·Rx) as the
    aerospace convention's roll, pitch (-90..90) and heading (-180..180, 0 north, clockwise), degrees. The body y and
    z axes turn round, so the pitch changes sign; the heading counts from north the other way. A pitch past 90° is
    the same attitude with the roll and heading turned by 180° (the model's integrated angles may pass it while it
    tumbles)."""
    roll = _wrap180(math.degrees(roll_rad))
    pitch = _wrap180(-math.degrees(pitch_rad))
    heading = _wrap180(90.0 - math.degrees(yaw_rad))
    if pitch > 90.0 or pitch < -90.0:
        pitch = math.copysign(180.0, pitch) - pitch
        roll = _wrap180(roll + 180.0)
        heading = _wrap180(heading + 180.0)
    return roll, pitch, heading


def truth_from_line(doc: Mapping[str, Any], home: tuple[float, float, float], seq: int,
                    time_scale: float = 1.0) -> VehicleTruth:
    """One decoded truth line → a :class:`VehicleTruth` (``time_s`` = the line's ``t``; ``home``: the .conf's
    HOME_LAT, HOME_LON, HOME_ALT, the simulator's origin). :class:`BadTruthLine` says why a line is refused."""
    try:
        t = float(doc["t"])
        x = [float(v) for v in doc["x"]]
    except (KeyError, TypeError, ValueError) as exc:
        raise BadTruthLine(f"no usable t and x: {exc}") from None
    if len(x) < STATES or not all(math.isfinite(v) for v in x) or not math.isfinite(t) or t < 0.0:
        raise BadTruthLine(f"t={doc.get('t')!r}, x of {len(x)} values: not a state")
    lat, lon, alt = LocalFrame(*home).to_geo(x[0], x[1], x[2])
    roll, pitch, heading = aerospace_attitude(x[3], x[4], x[5])
    return VehicleTruth(seq=seq, time_s=t, time_scale=time_scale, home=home, lat=lat, lon=lon, alt=alt,
                        vel_neu=(x[7], x[6], x[8]), roll=roll, pitch=pitch, heading=heading)


def truth_from_bytes(line: bytes, home: tuple[float, float, float], seq: int) -> VehicleTruth:
    """A raw line of the stream (a line cut by a lost write is refused: :class:`BadTruthLine`)."""
    try:
        doc = json.loads(line)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BadTruthLine(f"not JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise BadTruthLine("not a JSON object")
    return truth_from_line(doc, home, seq)
