"""Georeference a loaded log: every valid point into a local ENU frame whose origin is the first valid pose.

For a point p_s in the scanner frame of a scan with pose (Euler, LLA, velocity, UTC):

    p_body = R(mounting) · p_s + t_mounting                      scanner → MTi-G body frame
    p_ecef = ecef(LLA) + R_ecef←NWU(lat, lon) · (R_NWU←body(Euler) · p_body + v_NWU · Δt)
    p_enu  = R_ENU←ecef(origin) · (p_ecef − ecef(origin))

Δt = (scan start + point offset) − pose UTC moves the IMU along its velocity to the instant the point was
measured. It needs the scanner clock on UTC; with ``time_align=None`` it is used only when the log shows it
(scan timestamps within 1 s of the pose UTC), otherwise Δt = 0. The MTi-G reports the IMU position (it
applies the lever arm itself); for a log whose position is the GPS antenna's, ``position_ref="antenna"``
subtracts R_ecef←body · lever_arm. Using ECEF in the middle keeps the result exact over any distance instead
of a flat-earth approximation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modules.lidar_logger.geodesy import ecef_from_enu, ecef_from_nwu, euler_to_matrix, lla_to_ecef
from modules.lidar_logger.logdata import LidarLog

CHUNK = 1 << 18
SYNC_LIMIT_S = 1.0


class GeorefError(ValueError):
    pass


@dataclass(frozen=True)
class Mounting:
    """Scanner in the MTi-G body frame: p_body = Rz(yaw) Ry(pitch) Rx(roll) · p_scanner + (x, y, z).

    The default, pitch 90°, points the scanner's x axis (out of its window) straight down and sweeps its
    scan plane across the flight direction.
    """

    roll: float = 0.0
    pitch: float = 90.0
    yaw: float = 0.0
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0

    @property
    def rotation(self) -> np.ndarray:
        return euler_to_matrix(np.array([self.roll, self.pitch, self.yaw]))

    @property
    def translation(self) -> np.ndarray:
        return np.array([self.x, self.y, self.z])


@dataclass(frozen=True)
class GeorefResult:
    enu: np.ndarray
    """(N, 3) east, north, up in metres from ``origin_lla``."""
    origin_lla: np.ndarray
    point_index: np.ndarray
    """Index into the log's point arrays of each georeferenced point."""
    time_aligned: bool
    skipped_invalid_points: int
    skipped_invalid_pose: int
    skipped_pose_gap: int = 0
    """Points measured where the pose track has a gap (``interpolate_poses``): left out, not extrapolated."""


def clocks_synchronised(log: LidarLog) -> bool:
    """True when every scan with a valid pose has a pose UTC within 1 s of its scan end time."""
    sel = log.valid == 1
    if not sel.any():
        return False
    gap = np.abs(log.end_time[sel] - log.pose_time[sel])
    return bool(np.all(np.isfinite(gap)) and np.all(gap < SYNC_LIMIT_S))


def georeference(log: LidarLog, mounting: Mounting = Mounting(), *,
                 lever_arm: tuple[float, float, float] = (0.0, 0.0, 0.0), position_ref: str = "imu",
                 time_align: bool | None = None, origin_lla: np.ndarray | None = None,
                 select: np.ndarray | None = None, interpolate_poses: bool = False) -> GeorefResult:
    """Points of scans with a valid pose into ENU; ``select`` (a boolean per point) replaces the default
    choice of points (``Valid 1``: no flag set), e.g. to keep the points the scanner labelled ground.

    ``interpolate_poses`` (needs time alignment): each point takes the pose interpolated at its own time
    between the two logged poses around it (position linear, Euler angles linear with yaw unwrapped) instead of
    its scan's pose moved along the velocity, so attitude changes between poses (a helicopter's attitude loop,
    turns) are followed. A point between two poses more than ``MAX_POSE_GAP_S`` apart, or further than that
    before the first or after the last, is left out and counted (``skipped_pose_gap``): seconds of motion
    extrapolated along one velocity put turning ground metres off (a logger starved of CPU loses poses)."""
    if position_ref not in ("imu", "antenna"):
        raise GeorefError(f"position_ref must be 'imu' or 'antenna', not {position_ref!r}")
    pose_ok = log.valid == 1
    if not pose_ok.any():
        raise GeorefError(f"{log.source}: no scan has a valid pose")
    aligned = clocks_synchronised(log) if time_align is None else time_align
    if aligned and not np.all(np.isfinite(log.pose_time[pose_ok])):
        raise GeorefError(f"{log.source}: time alignment needs a valid UTC on every pose")
    if origin_lla is None:
        origin_lla = log.lla[np.argmax(pose_ok)]
    origin_lla = np.asarray(origin_lla, dtype=np.float64)

    point_ok = log.point_valid == 1 if select is None else np.asarray(select, dtype=bool)
    with_pose = pose_ok[log.point_scan]
    keep = np.nonzero(point_ok & with_pose)[0]

    r_ecef_nwu = ecef_from_nwu(log.lla[:, 0], log.lla[:, 1])
    r_ecef_body = r_ecef_nwu @ euler_to_matrix(log.euler)
    pos = lla_to_ecef(log.lla)
    if position_ref == "antenna":
        pos = pos - np.einsum("sij,j->si", r_ecef_body, np.asarray(lever_arm, dtype=np.float64))
    vel = np.einsum("sij,sj->si", r_ecef_nwu, log.vel)
    origin = lla_to_ecef(origin_lla)
    r_ecef_enu0 = ecef_from_enu(origin_lla[0], origin_lla[1])
    r_m, t_m = mounting.rotation, mounting.translation

    track = _PoseTrack(log, pose_ok, pos, vel, r_ecef_nwu) if interpolate_poses and aligned else None
    out = np.empty((len(keep), 3))
    covered = np.ones(len(keep), dtype=bool)
    for a in range(0, len(keep), CHUNK):
        idx = keep[a:a + CHUNK]
        s = log.point_scan[idx]
        p_body = log.xyz[idx] @ r_m.T + t_m
        if track is not None:
            p_imu, r_body, ok = track.at(log.start_time[s] + log.offset_us[idx] * 1e-6)
            covered[a:a + len(idx)] = ok
            p = p_imu + np.einsum("nij,nj->ni", r_body, p_body)
        else:
            p = pos[s] + np.einsum("nij,nj->ni", r_ecef_body[s], p_body)
            if aligned:
                dt = (log.start_time[s] - log.pose_time[s]) + log.offset_us[idx] * 1e-6
                p += vel[s] * dt[:, None]
        out[a:a + len(idx)] = (p - origin) @ r_ecef_enu0
    return GeorefResult(out[covered], origin_lla, keep[covered], aligned,
                        skipped_invalid_points=int((~point_ok & with_pose).sum()),
                        skipped_invalid_pose=int((~with_pose).sum()), skipped_pose_gap=int((~covered).sum()))


MAX_POSE_GAP_S = 0.5
"""Poses further apart than this are not interpolated between (a dropout): the points there are left out."""


class _PoseTrack:
    """The log's distinct valid poses in time order, interpolated at point times (``interpolate_poses``)."""

    def __init__(self, log: LidarLog, pose_ok: np.ndarray, pos: np.ndarray, vel: np.ndarray,
                 r_ecef_nwu: np.ndarray) -> None:
        rows = np.nonzero(pose_ok)[0]
        self.t, first = np.unique(log.pose_time[rows], return_index=True)
        src = rows[first]
        self.pos, self.vel, self.frame = pos[src], vel[src], r_ecef_nwu[src]
        euler = log.euler[src].copy()
        euler[:, 2] = np.degrees(np.unwrap(np.radians(euler[:, 2])))
        self.euler = euler

    def at(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """IMU position (ECEF), R_ecef←body at UTC ``tau``, and which points the track covers (between two poses
        at most ``MAX_POSE_GAP_S`` apart, or within that of its ends, moved along the end pose's velocity)."""
        n = len(self.t)
        if n < 2:
            dt = tau - self.t[0]
            return (self.pos[0] + self.vel[0] * dt[:, None], np.broadcast_to(self.frame[0] @ euler_to_matrix(
                self.euler[0]), (len(tau), 3, 3)).copy(), np.abs(dt) <= MAX_POSE_GAP_S)
        k = np.clip(np.searchsorted(self.t, tau, side="right") - 1, 0, n - 2)
        span = self.t[k + 1] - self.t[k]
        tc = np.clip(tau, self.t[k], self.t[k + 1])
        u = ((tc - self.t[k]) / span)[:, None]
        p = self.pos[k] + (self.pos[k + 1] - self.pos[k]) * u
        end = np.where(tau > self.t[k + 1], k + 1, k)  # before the first / after the last pose: along its velocity
        p += self.vel[end] * (tau - tc)[:, None]
        e = self.euler[k] + (self.euler[k + 1] - self.euler[k]) * u
        r = self.frame[k] @ euler_to_matrix(e)
        ok = (span <= MAX_POSE_GAP_S) & (np.abs(tau - tc) <= MAX_POSE_GAP_S)
        return p, r, ok
