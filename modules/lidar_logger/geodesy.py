"""The MTi-G's frames and rotations, shared by georeferencing and the simulator, over the project's WGS84
(:mod:`bbcs.geodesy`: ECEF and the ENU basis, re-exported here). Angles in degrees, lengths in m.

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

from bbcs.geodesy import ecef_from_enu, ecef_to_lla, lla_to_ecef

__all__ = ["ENU_FROM_NWU", "ecef_from_enu", "ecef_from_nwu", "ecef_to_lla", "euler_to_matrix", "lla_to_ecef",
           "matrix_to_euler"]

ENU_FROM_NWU = np.array([[0.0, -1.0, 0.0],
                         [1.0, 0.0, 0.0],
                         [0.0, 0.0, 1.0]])
"""east = -west, north = north, up = up."""


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
