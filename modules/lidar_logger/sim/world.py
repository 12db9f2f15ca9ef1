"""The simulated world both device simulators share: a clock, a terrain, and an aircraft flying over it.

The terrain is an analytic height field z = h(e, n) in a local ENU frame anchored at ``origin_lla`` (the
"terrain frame"). The aircraft (its IMU) flies straight legs between waypoints at constant speed and height,
with constant roll/pitch and a crab angle on each leg. Poses are reported the way an MTi-G reports them:
geodetic LLA, Euler angles and velocity in the local NWU frame *at the aircraft* (not the terrain frame),
so the georeferencing code is checked against exact geodesy, not a flat-earth shortcut.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from modules.lidar_logger.clock import Clock, ScaledClock
from modules.lidar_logger.geodesy import (
    ENU_FROM_NWU,
    ecef_from_enu,
    ecef_from_nwu,
    ecef_to_lla,
    euler_to_matrix,
    lla_to_ecef,
    matrix_to_euler,
)
from modules.lidar_logger.georef import Mounting
from modules.lidar_logger.mtdata import (
    STATUS_GPS_FIX,
    STATUS_SELFTEST_OK,
    STATUS_XKF_VALID,
    Pose,
    UtcTime,
    utc_from_posix,
)
from modules.lidar_logger.sim.follow import FollowedFlight

SEED_UTC_START = 1284103800.0
"""2010-09-10T07:30:00Z, the day of the seed's Figure 44 flights."""


@dataclass(frozen=True)
class Terrain:
    """h(e, n) = base + slope_e·e + slope_n·n + Σ amp·sin(2π e/λe)·cos(2π n/λn), metres, terrain frame."""

    base: float = 0.0
    slope_e: float = 0.03
    slope_n: float = -0.02
    waves: tuple[tuple[float, float, float], ...] = ((4.0, 200.0, 160.0), (1.5, 55.0, 70.0))
    """(amplitude, wavelength east, wavelength north)."""

    def height(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        e = np.asarray(e, dtype=np.float64)
        n = np.asarray(n, dtype=np.float64)
        h = self.base + self.slope_e * e + self.slope_n * n
        for amp, le, ln in self.waves:
            h = h + amp * np.sin(2 * np.pi * e / le) * np.cos(2 * np.pi * n / ln)
        return h

    @property
    def max_slope(self) -> float:
        """An upper bound of |∇h| over the whole plane."""
        ge = abs(self.slope_e) + sum(amp * 2 * math.pi / le for amp, le, _ in self.waves)
        gn = abs(self.slope_n) + sum(amp * 2 * math.pi / ln for amp, _, ln in self.waves)
        return math.hypot(ge, gn)

    def gradient(self, e: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(∂h/∂e, ∂h/∂n)."""
        ge = np.full(np.shape(e), self.slope_e)
        gn = np.full(np.shape(n), self.slope_n)
        for amp, le, ln in self.waves:
            ke, kn = 2 * np.pi / le, 2 * np.pi / ln
            ge = ge + amp * ke * np.cos(ke * e) * np.cos(kn * n)
            gn = gn - amp * kn * np.sin(ke * e) * np.sin(kn * n)
        return ge, gn

    def ray_cast(self, origins: np.ndarray, dirs: np.ndarray, max_range: float) -> np.ndarray:
        """Distance along each unit ray to the terrain (NaN when it misses within ``max_range``).

        f(s) = z(s) − h(x(s), y(s)) is strictly decreasing on a ray with d_z + max_slope·|d_xy| < 0, so it
        has one root in [0, max_range] when f(0) > 0 > f(max_range); other rays are first bracketed by
        marching in 0.5 m steps. The root is polished by Newton steps kept inside the bracket (bisection
        when a step would leave it) until |f| < 1e-9 m.
        """
        o = np.asarray(origins, dtype=np.float64)
        d = np.asarray(dirs, dtype=np.float64)

        def f(s: np.ndarray, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
            p = o[rows] + d[rows] * s[:, None]
            return p[:, 2] - self.height(p[:, 0], p[:, 1])

        n = len(o)
        lo = np.zeros(n)
        hi = np.full(n, float(max_range))
        above = f(lo) > 0
        monotone = d[:, 2] + self.max_slope * np.hypot(d[:, 0], d[:, 1]) < 0
        hit = above & monotone & (f(hi) < 0)
        steep = np.nonzero(above & ~monotone)[0]
        if len(steep):
            grid = np.arange(0.0, max_range + 0.5, 0.5)
            found = np.zeros(len(steep), dtype=bool)
            for a, b in zip(grid[:-1], grid[1:], strict=True):
                below = (f(np.full(len(steep), b), steep) < 0) & ~found
                lo[steep[below]], hi[steep[below]] = a, b
                found |= below
            hit[steep] = found
        rows = np.nonzero(hit)[0]
        lo_r, hi_r = lo[rows], hi[rows]
        o_r, d_r = o[rows], d[rows]
        s = 0.5 * (lo_r + hi_r)
        for _ in range(60):
            p = o_r + d_r * s[:, None]
            fs = p[:, 2] - self.height(p[:, 0], p[:, 1])
            if not len(fs) or np.max(np.abs(fs)) < 1e-9:
                break
            pos = fs > 0
            lo_r = np.where(pos, s, lo_r)
            hi_r = np.where(pos, hi_r, s)
            ge, gn = self.gradient(p[:, 0], p[:, 1])
            slope = d_r[:, 2] - ge * d_r[:, 0] - gn * d_r[:, 1]
            with np.errstate(divide="ignore", invalid="ignore"):
                step = s - fs / slope
            inside = (step >= lo_r) & (step <= hi_r)
            s = np.where(np.abs(fs) < 1e-9, s, np.where(inside, step, 0.5 * (lo_r + hi_r)))
        out = np.full(n, np.nan)
        out[rows] = s
        return out


@dataclass(frozen=True)
class Flight:
    """Straight legs through ``waypoints`` (east, north in the terrain frame) at ``height`` and ``speed``.

    On every leg the body is yawed to the leg's track plus ``crab`` and held at ``roll`` and ``pitch``
    (degrees, the MTi-G's Euler convention). After the last waypoint the last leg continues.
    """

    waypoints: tuple[tuple[float, float], ...] = ((-600.0, -350.0), (600.0, 350.0))
    height: float = 90.0
    speed: float = 20.0
    roll: float = 2.0
    pitch: float = -1.5
    crab: float = 3.0
    start_time: float = 0.0
    """Clock time at which the aircraft is at the first waypoint."""

    def __post_init__(self) -> None:
        if len(self.waypoints) < 2 or self.speed <= 0:
            raise ValueError("a flight needs two waypoints and a positive speed")

    def _legs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        w = np.asarray(self.waypoints, dtype=np.float64)
        seg = np.diff(w, axis=0)
        length = np.hypot(seg[:, 0], seg[:, 1])
        t_start = self.start_time + np.concatenate(([0.0], np.cumsum(length[:-1]))) / self.speed
        return w[:-1], seg / length[:, None], t_start

    def state(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position (N,3), velocity (N,3) and R_terrainENU←body (N,3,3) at clock times ``t``."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        starts, units, t0 = self._legs()
        leg = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, len(t0) - 1)
        dist = (t - t0[leg]) * self.speed
        pos = np.empty((len(t), 3))
        pos[:, :2] = starts[leg] + units[leg] * dist[:, None]
        pos[:, 2] = self.height
        vel = np.zeros((len(t), 3))
        vel[:, :2] = units[leg] * self.speed
        track_ccw_from_north = np.degrees(np.arctan2(-units[leg, 0], units[leg, 1]))
        euler = np.stack((np.full(len(t), self.roll), np.full(len(t), self.pitch),
                          track_ccw_from_north - self.crab), axis=-1)
        rot = ENU_FROM_NWU @ euler_to_matrix(euler)
        return pos, vel, rot


@dataclass
class World:
    clock: Clock = field(default_factory=lambda: ScaledClock(1.0))
    utc_start: float = SEED_UTC_START
    """UTC (POSIX seconds) at clock time 0."""
    origin_lla: tuple[float, float, float] = (37.4261, -6.0032, 50.0)
    terrain: Terrain = field(default_factory=Terrain)
    flight: Flight | FollowedFlight = field(default_factory=Flight)
    """Straight legs (``Flight``), or the DSP simulator's aircraft (``FollowedFlight``, sim/follow.py)."""
    mounting: Mounting = field(default_factory=Mounting)
    """Where the simulated scanner really sits on the body."""
    gps_fix_at: float = 1.0
    """Clock time the status byte goes 0 → 5 (self-test ok, GPS fix)."""
    xkf_valid_at: float = 2.0
    """Clock time the status byte goes 5 → 7 (XKF valid)."""
    dropouts: tuple[tuple[float, float], ...] = ()
    """Clock intervals with status 5 (XKF not valid) after ``xkf_valid_at``."""

    def __post_init__(self) -> None:
        self._origin_ecef = lla_to_ecef(np.array(self.origin_lla))
        self._ecef_from_terrain = ecef_from_enu(self.origin_lla[0], self.origin_lla[1])

    def set_origin(self, origin_lla: tuple[float, float, float]) -> None:
        """Anchor the terrain frame elsewhere (a followed aircraft's home, ``sim/follow.py``)."""
        self.origin_lla = (float(origin_lla[0]), float(origin_lla[1]), float(origin_lla[2]))
        self.__post_init__()

    def now(self) -> float:
        return self.clock.now()

    def utc(self, t: float) -> float:
        return self.utc_start + t

    def status(self, t: float) -> int:
        if t < self.gps_fix_at:
            return 0
        if t < self.xkf_valid_at or any(a <= t < b for a, b in self.dropouts):
            return STATUS_SELFTEST_OK | STATUS_GPS_FIX
        return STATUS_SELFTEST_OK | STATUS_GPS_FIX | STATUS_XKF_VALID

    def terrain_to_lla(self, p: np.ndarray) -> np.ndarray:
        return ecef_to_lla(self._origin_ecef + np.asarray(p) @ self._ecef_from_terrain.T)

    def lla_to_terrain(self, lla: np.ndarray) -> np.ndarray:
        return (lla_to_ecef(lla) - self._origin_ecef) @ self._ecef_from_terrain

    def enu_to_terrain(self, enu: np.ndarray, enu_origin_lla: np.ndarray) -> np.ndarray:
        """Points of another ENU frame (origin ``enu_origin_lla``) in the terrain frame."""
        ecef = lla_to_ecef(np.asarray(enu_origin_lla)) + np.asarray(enu) @ ecef_from_enu(
            enu_origin_lla[0], enu_origin_lla[1]).T
        return (ecef - self._origin_ecef) @ self._ecef_from_terrain

    def true_pose(self, t: float) -> Pose:
        """What a perfect MTi-G reports at clock time ``t`` (with the status byte of that moment)."""
        status = self.status(t)
        utc = utc_from_posix(self.utc(t))
        if status == 0:
            zero = UtcTime(nano=0, year=0, month=0, day=0, hour=0, minute=0, second=0, flags=0)
            return Pose(utc=zero, euler=(0.0, 0.0, 0.0), lla=(0.0, 0.0, 0.0), vel=(0.0, 0.0, 0.0),
                        status=0, valid=0)
        pos, vel, rot = self.flight.state(np.array([t]))
        lla = self.terrain_to_lla(pos[0])
        nwu_from_ecef = ecef_from_nwu(lla[0], lla[1]).T
        euler = matrix_to_euler(nwu_from_ecef @ self._ecef_from_terrain @ rot[0])
        v_nwu = nwu_from_ecef @ self._ecef_from_terrain @ vel[0]
        return Pose(utc=utc, euler=tuple(float(a) for a in euler), lla=tuple(float(a) for a in lla),
                    vel=tuple(float(a) for a in v_nwu), status=status,
                    valid=1 if status == 7 else 0)

    def beam_geometry(self, t: np.ndarray, dirs_scanner: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Origins and unit directions, in the terrain frame, of scanner-frame beams fired at times ``t``."""
        pos, _, rot = self.flight.state(t)
        r_m, t_m = self.mounting.rotation, self.mounting.translation
        origins = pos + np.einsum("nij,j->ni", rot, t_m)
        dirs = np.einsum("nij,nj->ni", rot, dirs_scanner @ r_m.T)
        return origins, dirs
