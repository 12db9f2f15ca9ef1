"""WGS84 geodesy and rotations shared by georeferencing and the simulator. Angles in degrees, lengths in m.

Frames:
- ECEF: WGS84 Earth-centred, Earth-fixed.
- ENU: local tangent frame at a point, x east, y north, z up.
- NWU: the MTi-G's default local frame (output settings without the NED bit): x north, y west, z up.
- body: the MTi-G sensor frame, x forward, y left, z up.

Euler angles are the Xsens convention: R_local←body = Rz(yaw) · Ry(pitch) · Rx(roll), applied to a body vector
as roll about x first, then pitch about y, then yaw about z, all in the NWU local frame.
"""

from __future__ import annotations

import numpy as np

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)

ENU_FROM_NWU = np.array([[0.0, -1.0, 0.0],
                         [1.0, 0.0, 0.0],
                         [0.0, 0.0, 1.0]])
"""east = -west, north = north, up = up."""


def lla_to_ecef(lla: np.ndarray) -> np.ndarray:
    """(..., 3) latitude, longitude [deg], ellipsoidal height [m] → (..., 3) ECEF [m]."""
    lla = np.asarray(lla, dtype=np.float64)
    lat, lon, h = np.radians(lla[..., 0]), np.radians(lla[..., 1]), lla[..., 2]
    sl, cl = np.sin(lat), np.cos(lat)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sl * sl)
    return np.stack(((n + h) * cl * np.cos(lon), (n + h) * cl * np.sin(lon), (n * (1.0 - WGS84_E2) + h) * sl),
                    axis=-1)


def ecef_to_lla(xyz: np.ndarray, iterations: int = 8) -> np.ndarray:
    """Inverse of ``lla_to_ecef`` by fixed-point iteration on latitude (sub-micrometre after a few steps
    anywhere near the surface)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - WGS84_E2))
    h = np.zeros_like(p)
    for _ in range(iterations):
        sl = np.sin(lat)
        n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sl * sl)
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1.0 - WGS84_E2 * n / (n + h)))
    return np.stack((np.degrees(lat), np.degrees(np.arctan2(y, x)), h), axis=-1)


def ecef_from_enu(lat_deg: np.ndarray | float, lon_deg: np.ndarray | float) -> np.ndarray:
    """(..., 3, 3) rotation whose columns are the east, north, up unit vectors in ECEF."""
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    zero = np.zeros_like(sl)
    east = np.stack((-so, co, zero), axis=-1)
    north = np.stack((-sl * co, -sl * so, cl), axis=-1)
    up = np.stack((cl * co, cl * so, sl), axis=-1)
    return np.stack((east, north, up), axis=-1)


def ecef_from_nwu(lat_deg: np.ndarray | float, lon_deg: np.ndarray | float) -> np.ndarray:
    return ecef_from_enu(lat_deg, lon_deg) @ ENU_FROM_NWU


def euler_to_matrix(euler_deg: np.ndarray) -> np.ndarray:
    """(..., 3) roll, pitch, yaw [deg] → (..., 3, 3) R = Rz(yaw) Ry(pitch) Rx(roll)."""
    e = np.radians(np.asarray(euler_deg, dtype=np.float64))
    r, p, y = e[..., 0], e[..., 1], e[..., 2]
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.stack((
        np.stack((cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr), axis=-1),
        np.stack((sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr), axis=-1),
        np.stack((-sp, cp * sr, cp * cr), axis=-1),
    ), axis=-2)


def matrix_to_euler(r: np.ndarray) -> np.ndarray:
    """Inverse of ``euler_to_matrix`` for |pitch| < 90°."""
    r = np.asarray(r, dtype=np.float64)
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    pitch = -np.arcsin(np.clip(r[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    return np.degrees(np.stack((roll, pitch, yaw), axis=-1))
