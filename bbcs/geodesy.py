"""The project's one Earth model: WGS84, a local east/north/up frame, distances, bearings, offsets, ECEF.

Why one: the RAL judges a goto's arrival, the DSP simulator flies it, the path follower and the trajectory
generator plan it, vision and the logger georeference with it. When each of them used its own Earth (a 6,371 km
sphere here, the equatorial radius there, 111,320 m per degree elsewhere), two processes could disagree by
~0.5% about the same distance. Every Earth constant lives here and nowhere else (tests/test_single_declaration.py).

Why a linearised frame and not a full tangent plane: the robots work within a few km of a reference, and
linearising geodetic coordinates there (the WGS84 meridian and prime-vertical radii at the reference latitude)
makes "up" exactly the altitude and the conversion exactly invertible; against exact geodesy the horizontal
error grows as d²/R, under 0.2 m at 1 km. :func:`lla_to_ecef` and friends are exact, for the logger's
georeferencing. Angles are degrees, lengths metres; latitude/longitude ranges are those of
:mod:`bbcs.contracts.geo`.
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bbcs.contracts.geo import Latitude, Longitude

WGS84_A = 6_378_137.0
"""Semi-major axis, metres."""
WGS84_F = 1.0 / 298.257223563
"""Flattening."""
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
"""First eccentricity squared."""

MAX_REF_LAT_DEG = 89.0
"""The east scale collapses at the poles: a frame is refused closer to one than this."""

T = TypeVar("T", float, NDArray[np.float64])


_LAT = typing.get_args(Latitude)[1]
_LON = typing.get_args(Longitude)[1]
LAT_RANGE: tuple[float, float] = (_LAT.ge, _LAT.le)
"""The contracts' latitude range (bbcs.contracts.geo), read from its alias: declared there only."""
LON_RANGE: tuple[float, float] = (_LON.ge, _LON.le)
"""The contracts' longitude range, likewise."""


def check_lla(lat: float, lon: float, alt: float = 0.0) -> None:
    """ValueError naming the field when a position is outside the contracts' ranges or not finite."""
    for name, value, (lo, hi) in (("latitude", lat, LAT_RANGE), ("longitude", lon, LON_RANGE)):
        if not (math.isfinite(value) and lo <= value <= hi):
            raise ValueError(f"{name} {value!r} outside [{lo:g}, {hi:g}]")
    if not math.isfinite(alt):
        raise ValueError(f"altitude {alt!r} is not finite")


def valid_lat_lon(lat: float, lon: float) -> bool:
    """Whether a position is inside the contracts' ranges (for checks that report their own error)."""
    return (math.isfinite(lat) and math.isfinite(lon) and LAT_RANGE[0] <= lat <= LAT_RANGE[1]
            and LON_RANGE[0] <= lon <= LON_RANGE[1])


def wrap_lon(lon_deg: T) -> T:
    """Longitude(s) into [-180, 180): a frame near the antimeridian sees both sides as neighbours. A longitude
    already inside is returned as it is (the modulo would round it)."""
    lo, hi = LON_RANGE
    if isinstance(lon_deg, np.ndarray):
        return np.where((lon_deg >= lo) & (lon_deg < hi), lon_deg, (lon_deg - lo) % (hi - lo) + lo)
    return lon_deg if lo <= lon_deg < hi else (lon_deg - lo) % (hi - lo) + lo


def metres_per_degree(lat_deg: float, alt: float = 0.0) -> tuple[float, float]:
    """Metres per degree of latitude (north) and of longitude (east) at ``lat_deg``, ``alt`` above the ellipsoid."""
    phi = math.radians(lat_deg)
    w = 1.0 - WGS84_E2 * math.sin(phi) ** 2
    meridian = WGS84_A * (1.0 - WGS84_E2) / w**1.5 + alt
    prime = WGS84_A / math.sqrt(w) + alt
    return math.radians(meridian), math.radians(prime * math.cos(phi))


@dataclass(frozen=True, slots=True)
class LocalFrame:
    """East/north/up metres around a reference (``lat0``, ``lon0`` degrees, ``alt0`` metres).

    ``to_local``/``to_geo`` take floats or numpy arrays alike (plain arithmetic); ``to_enu``/``to_lla`` stack
    arrays (..., 3) for vectorised callers."""

    lat0: float
    lon0: float
    alt0: float = 0.0
    north_per_deg: float = field(init=False, repr=False)
    east_per_deg: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        check_lla(self.lat0, self.lon0, self.alt0)
        if abs(self.lat0) > MAX_REF_LAT_DEG:
            raise ValueError(f"reference latitude {self.lat0} too close to a pole (limit ±{MAX_REF_LAT_DEG})")
        n, e = metres_per_degree(self.lat0, self.alt0)
        object.__setattr__(self, "north_per_deg", n)
        object.__setattr__(self, "east_per_deg", e)

    def to_local(self, lat: T, lon: T, alt: T | float = 0.0) -> tuple[T, T, T]:
        """(east, north, up) metres of a position (or arrays of them)."""
        east = wrap_lon(lon - self.lon0) * self.east_per_deg
        return east, (lat - self.lat0) * self.north_per_deg, alt - self.alt0  # type: ignore[return-value]

    def to_geo(self, east: T, north: T, up: T | float = 0.0) -> tuple[T, T, T]:
        """(lat, lon, alt) of a local point (or arrays); the inverse of :meth:`to_local`."""
        lat = self.lat0 + north / self.north_per_deg
        lon = wrap_lon(self.lon0 + east / self.east_per_deg)
        return lat, lon, self.alt0 + up  # type: ignore[return-value]

    def to_enu(self, lat: ArrayLike, lon: ArrayLike, alt: ArrayLike) -> NDArray[np.float64]:
        """LLA (scalars or arrays) -> array (..., 3) of east, north, up."""
        e, n, u = self.to_local(np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64),
                                np.asarray(alt, dtype=np.float64))
        return np.stack(np.broadcast_arrays(e, n, u), axis=-1)

    def to_lla(self, enu: ArrayLike) -> NDArray[np.float64]:
        """Array (..., 3) of east, north, up -> array (..., 3) of lat, lon, alt.

        ValueError if a latitude would leave [-90, 90] (the point is past a pole)."""
        p = np.asarray(enu, dtype=np.float64)
        lat, lon, alt = self.to_geo(p[..., 0], p[..., 1], p[..., 2])
        if not np.all((lat >= LAT_RANGE[0]) & (lat <= LAT_RANGE[1])):
            raise ValueError(f"local point maps to a latitude outside [{LAT_RANGE[0]:g}, {LAT_RANGE[1]:g}]")
        return np.stack(np.broadcast_arrays(lat, lon, alt), axis=-1)


def distance_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Horizontal metres between two positions (the frame at their mean latitude: metre-accurate over km)."""
    n_per_deg, e_per_deg = metres_per_degree((lat1 + lat2) / 2.0)
    return math.hypot((lat2 - lat1) * n_per_deg, wrap_lon(lon2 - lon1) * e_per_deg)


def bearing_deg(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Direction from the first position to the second, degrees in [-180, 180), 0 = north, clockwise."""
    n_per_deg, e_per_deg = metres_per_degree((lat1 + lat2) / 2.0)
    b = math.degrees(math.atan2(wrap_lon(lon2 - lon1) * e_per_deg, (lat2 - lat1) * n_per_deg))
    return -180.0 if b >= 180.0 else b


def local_en(lat0: float, lon0: float, lat: float, lon: float) -> tuple[float, float]:
    """East, north metres of (lat, lon) from (lat0, lon0), at the scale of ``lat0`` (as :class:`LocalFrame`)."""
    n_per_deg, e_per_deg = metres_per_degree(lat0)
    return wrap_lon(lon - lon0) * e_per_deg, (lat - lat0) * n_per_deg


def offset(lat: float, lon: float, north_m: float, east_m: float) -> tuple[float, float]:
    """The position ``north_m``/``east_m`` metres from (lat, lon): the inverse of :func:`local_en`."""
    n_per_deg, e_per_deg = metres_per_degree(lat)
    return lat + north_m / n_per_deg, wrap_lon(lon + east_m / e_per_deg)


# ---------------------------------------------------------------- exact: Earth-centred, Earth-fixed


def lla_to_ecef(lla: ArrayLike) -> NDArray[np.float64]:
    """(..., 3) latitude, longitude [deg], ellipsoidal height [m] -> (..., 3) ECEF [m]."""
    a = np.asarray(lla, dtype=np.float64)
    lat, lon, h = np.radians(a[..., 0]), np.radians(a[..., 1]), a[..., 2]
    sl, cl = np.sin(lat), np.cos(lat)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sl * sl)
    return np.stack(((n + h) * cl * np.cos(lon), (n + h) * cl * np.sin(lon), (n * (1.0 - WGS84_E2) + h) * sl),
                    axis=-1)


def ecef_to_lla(xyz: ArrayLike, iterations: int = 8) -> NDArray[np.float64]:
    """Inverse of :func:`lla_to_ecef` by fixed-point iteration on latitude (sub-micrometre near the surface)."""
    a = np.asarray(xyz, dtype=np.float64)
    x, y, z = a[..., 0], a[..., 1], a[..., 2]
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - WGS84_E2))
    h = np.zeros_like(p)
    for _ in range(iterations):
        sl = np.sin(lat)
        n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sl * sl)
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1.0 - WGS84_E2 * n / (n + h)))
    return np.stack((np.degrees(lat), np.degrees(np.arctan2(y, x)), h), axis=-1)


def ecef_from_enu(lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray[np.float64]:
    """(..., 3, 3) rotation whose columns are the east, north, up unit vectors in ECEF."""
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    zero = np.zeros_like(sl)
    east = np.stack((-so, co, zero), axis=-1)
    north = np.stack((-sl * co, -sl * so, cl), axis=-1)
    up = np.stack((cl * co, cl * so, sl), axis=-1)
    return np.stack((east, north, up), axis=-1)
