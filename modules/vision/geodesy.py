"""Local level frame: latitude/longitude/altitude <-> east/north/up metres around a reference point.

Why not a full ECEF tangent plane: the vision module works within a few hundred metres of the aircraft and
assumes *flat ground at a given altitude*. Linearising geodetic coordinates around the reference (WGS84
meridian and prime-vertical radii at the reference latitude) makes "up" exactly the altitude, so that flat
ground is exactly the plane ``up = ground_alt - ref_alt``, and the conversion is exactly invertible. Against
true geodesy the horizontal error grows as d²/R: below 0.2 m at 1 km from the reference at mid latitudes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)

#: The east scale collapses at the poles; references closer than this to a pole are refused.
MAX_REF_LAT_DEG = 89.0


def wrap_lon(lon_deg: ArrayLike) -> NDArray[np.float64] | float:
    """Wrap longitude(s) into [-180, 180)."""
    wrapped = (np.asarray(lon_deg, dtype=np.float64) + 180.0) % 360.0 - 180.0
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped


def wrap_deg(angle_deg: float) -> float:
    """Wrap an angle into [-180, 180]; +180 stays +180 so it matches the DATOS_PT pan range."""
    a = (angle_deg + 180.0) % 360.0 - 180.0
    return 180.0 if a == -180.0 and angle_deg > 0 else a


def check_lla(lat: float, lon: float, alt: float) -> None:
    """Raise ValueError naming the field when a position is out of range or not finite."""
    if not (math.isfinite(lat) and -90.0 <= lat <= 90.0):
        raise ValueError(f"latitude {lat!r} outside [-90, 90]")
    if not (math.isfinite(lon) and -180.0 <= lon <= 180.0):
        raise ValueError(f"longitude {lon!r} outside [-180, 180]")
    if not math.isfinite(alt):
        raise ValueError(f"altitude {alt!r} is not finite")


@dataclass(frozen=True, slots=True)
class LocalFrame:
    """East/north/up metres around a reference (lat, lon in degrees, alt in metres)."""

    lat0: float
    lon0: float
    alt0: float = 0.0

    def __post_init__(self) -> None:
        check_lla(self.lat0, self.lon0, self.alt0)
        if abs(self.lat0) > MAX_REF_LAT_DEG:
            raise ValueError(f"reference latitude {self.lat0} too close to a pole (limit ±{MAX_REF_LAT_DEG})")

    @property
    def _radii(self) -> tuple[float, float]:
        """Metres per radian of latitude and of longitude at the reference."""
        phi = math.radians(self.lat0)
        w = 1.0 - WGS84_E2 * math.sin(phi) ** 2
        meridian = WGS84_A * (1.0 - WGS84_E2) / w**1.5 + self.alt0
        prime = WGS84_A / math.sqrt(w) + self.alt0
        return meridian, prime * math.cos(phi)

    def to_enu(self, lat: ArrayLike, lon: ArrayLike, alt: ArrayLike) -> NDArray[np.float64]:
        """LLA (degrees, metres; scalars or arrays) -> array (..., 3) of east, north, up."""
        m_lat, m_lon = self._radii
        dlat = np.radians(np.asarray(lat, dtype=np.float64) - self.lat0)
        dlon = np.radians(wrap_lon(np.asarray(lon, dtype=np.float64) - self.lon0))
        up = np.asarray(alt, dtype=np.float64) - self.alt0
        return np.stack(np.broadcast_arrays(dlon * m_lon, dlat * m_lat, up), axis=-1)

    def to_lla(self, enu: ArrayLike) -> NDArray[np.float64]:
        """Array (..., 3) of east, north, up -> array (..., 3) of lat, lon (wrapped), alt.

        Raises ValueError if a latitude would leave [-90, 90] (the point is past a pole).
        """
        p = np.asarray(enu, dtype=np.float64)
        m_lat, m_lon = self._radii
        lat = self.lat0 + np.degrees(p[..., 1] / m_lat)
        lon = wrap_lon(self.lon0 + np.degrees(p[..., 0] / m_lon))
        if np.any(np.abs(lat) > 90.0) or not np.all(np.isfinite(lat)):
            raise ValueError("local point maps to a latitude outside [-90, 90]")
        return np.stack(np.broadcast_arrays(lat, lon, self.alt0 + p[..., 2]), axis=-1)
