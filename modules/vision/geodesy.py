"""Vision's geodesy is the project's (:mod:`bbcs.geodesy`: WGS84, a local frame linearised at a reference, so
flat ground at a given altitude is exactly the plane ``up = ground_alt - ref_alt``); only the gimbal's angle wrap
is vision's own."""

from __future__ import annotations

from bbcs.geodesy import LocalFrame, check_lla, wrap_lon

__all__ = ["LocalFrame", "check_lla", "wrap_deg", "wrap_lon"]


def wrap_deg(angle_deg: float) -> float:
    """Wrap an angle into [-180, 180]; +180 stays +180 so it matches the DATOS_PT pan range."""
    a = (angle_deg + 180.0) % 360.0 - 180.0
    return 180.0 if a == -180.0 and angle_deg > 0 else a
