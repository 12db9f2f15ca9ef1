"""Camera geometry: frames, the pinhole model, ray/ground intersection and its inverse (pointing angles).

Frames (all right-handed; see docs/vision.md):

- ENU: local level frame of ``geodesy.LocalFrame`` (x east, y north, z up).
- NED: x north, y east, z down. ``ENU_FROM_NED`` swaps x/y and negates z (it is its own inverse).
- body (FRD): x forward, y right, z down. ``R_ned_body = Rz(yaw) Ry(pitch) Rx(roll)`` (aerospace ZYX).
- mount (the frame the pan & tilt angles are measured in), one of:
  body-fixed: the body frame, ``R_ned_mount = R_ned_body``;
  stabilised: the body frame with roll and pitch compensated, ``R_ned_mount = Rz(yaw)``, so pan is measured
  from the heading and tilt from the horizon (what the DSP simulator's pan & tilt does).
- gimbal: x along the optical axis, y image right, z image down. ``R_mount_gimbal = Rz(pan) Ry(tilt)``:
  pan first (about the mount's z, down: positive turns right), then tilt (about the panned y axis: positive
  raises the optical axis, so tilt is the elevation and -90 is straight down).
- optical: x image right, y image down, z along the optical axis (the usual pinhole convention).
  ``GIMBAL_FROM_OPTICAL`` maps optical axes onto gimbal axes.

v_enu = ENU_FROM_NED @ R_ned_mount @ R_mount_gimbal @ GIMBAL_FROM_OPTICAL @ v_optical.
The camera's centre of projection is at the aircraft position (no lever arm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .geodesy import wrap_deg
from .pose import AircraftPose, Gimbal

ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
GIMBAL_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def rot_x(a: float) -> NDArray[np.float64]:
    """Rotation by ``a`` radians about x (active, right-handed)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> NDArray[np.float64]:
    """Rotation by ``a`` radians about y."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> NDArray[np.float64]:
    """Rotation by ``a`` radians about z."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def ned_from_body(roll_deg: float, pitch_deg: float, yaw_deg: float) -> NDArray[np.float64]:
    """Body (FRD) -> NED rotation for aerospace ZYX Euler angles in degrees."""
    return rot_z(math.radians(yaw_deg)) @ rot_y(math.radians(pitch_deg)) @ rot_x(math.radians(roll_deg))


def mount_from_optical(gimbal: Gimbal) -> NDArray[np.float64]:
    """Optical -> mount rotation for the pan & tilt angles."""
    return rot_z(math.radians(gimbal.pan)) @ rot_y(math.radians(gimbal.tilt)) @ GIMBAL_FROM_OPTICAL


def enu_from_body(pose: AircraftPose) -> NDArray[np.float64]:
    """Body -> ENU rotation for an aircraft attitude."""
    return ENU_FROM_NED @ ned_from_body(pose.roll, pose.pitch, pose.yaw)


def enu_from_mount(pose: AircraftPose, stabilised: bool) -> NDArray[np.float64]:
    """Mount -> ENU rotation: the whole attitude for a body-fixed mount, the heading only if stabilised."""
    if stabilised:
        return ENU_FROM_NED @ rot_z(math.radians(pose.yaw))
    return enu_from_body(pose)


def enu_from_optical(pose: AircraftPose, gimbal: Gimbal, stabilised: bool) -> NDArray[np.float64]:
    """Optical -> ENU rotation: the full chain from a pixel ray to the local level frame."""
    return enu_from_mount(pose, stabilised) @ mount_from_optical(gimbal)


@dataclass(frozen=True)
class CameraModel:
    """Ideal pinhole camera: square pixels, principal point at the image centre, no distortion.

    Pixel (u, v) = (column, row) and integer coordinates are pixel *centres*, so the principal point is
    ((width-1)/2, (height-1)/2). ``hfov_deg`` is the horizontal field of view across the full width.
    ``stabilised`` says how the pan & tilt unit is mounted (see the module docstring): True (default, as the
    DSP simulator models it) = angles relative to heading and horizon; False = relative to the airframe.
    """

    width: int = 640
    height: int = 480
    hfov_deg: float = 60.0
    stabilised: bool = True

    def __post_init__(self) -> None:
        if self.width < 2 or self.height < 2:
            raise ValueError(f"image size {self.width}x{self.height} too small")
        if not 1.0 <= self.hfov_deg <= 170.0:
            raise ValueError(f"horizontal field of view {self.hfov_deg} outside [1, 170] degrees")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (same on both axes)."""
        return (self.width / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def centre(self) -> tuple[float, float]:
        """Principal point (u, v) in pixels."""
        return (self.width - 1) / 2.0, (self.height - 1) / 2.0

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view implied by the square pixels."""
        return math.degrees(2.0 * math.atan((self.height / 2.0) / self.focal_px))

    def pixel_rays(self, u: ArrayLike, v: ArrayLike) -> NDArray[np.float64]:
        """Optical-frame ray directions (..., 3), z = 1, through pixel coordinates u, v."""
        cu, cv = self.centre
        f = self.focal_px
        u_arr, v_arr = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
        return np.stack(((u_arr - cu) / f, (v_arr - cv) / f, np.ones_like(u_arr)), axis=-1)

    def grid_axes(self) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Normalised image coordinates of the pixel centres: x per column (W,), y per row (H,).

        The optical ray through pixel (u, v) is (x[u], y[v], 1); keeping the two axes separate lets a
        renderer rotate all rays with broadcasting instead of a (H*W, 3) matrix product.
        """
        cu, cv = self.centre
        f = self.focal_px
        x = ((np.arange(self.width) - cu) / f).astype(np.float32)
        y = ((np.arange(self.height) - cv) / f).astype(np.float32)
        return x, y

    def project(self, points_optical: ArrayLike) -> NDArray[np.float64]:
        """Optical-frame points (..., 3) -> pixel (u, v) (..., 2); NaN for points not in front (z <= 0)."""
        p = np.asarray(points_optical, dtype=np.float64)
        z = np.where(p[..., 2] > 0.0, p[..., 2], np.nan)
        cu, cv = self.centre
        f = self.focal_px
        return np.stack((cu + f * p[..., 0] / z, cv + f * p[..., 1] / z), axis=-1)

    def contains(self, uv: ArrayLike) -> NDArray[np.bool_]:
        """True where pixel coordinates fall inside the image (pixel-centre bounds ±0.5)."""
        q = np.asarray(uv, dtype=np.float64)
        u, v = q[..., 0], q[..., 1]
        with np.errstate(invalid="ignore"):
            return (u >= -0.5) & (u <= self.width - 0.5) & (v >= -0.5) & (v <= self.height - 0.5)


def intersect_ground(
    origin: ArrayLike, directions: ArrayLike, ground_up: float, max_range: float = math.inf
) -> NDArray[np.float64]:
    """Intersect rays origin + t·d (t > 0) with the plane up = ``ground_up``.

    ``directions`` is (..., 3) in ENU, not necessarily unit. Returns (..., 3) ENU points, NaN where the ray
    points level/upwards, starts below the ground, or hits beyond ``max_range`` metres from the origin.
    """
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    dz = d[..., 2]
    height = o[2] - ground_up
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where((dz < 0.0) & (height >= 0.0), -height / dz, np.nan)
        hit = o + t[..., None] * d
        too_far = np.linalg.norm(hit - o, axis=-1) > max_range
    return np.where(too_far[..., None], np.nan, hit)


def pixel_to_enu(
    camera: CameraModel,
    pose: AircraftPose,
    gimbal: Gimbal,
    position_enu: ArrayLike,
    uv: tuple[float, float],
    ground_up: float,
    max_range: float = math.inf,
) -> NDArray[np.float64] | None:
    """Geolocate one pixel: ENU ground point seen at ``uv``, or None if its ray misses the ground."""
    ray = enu_from_optical(pose, gimbal, camera.stabilised) @ camera.pixel_rays(uv[0], uv[1])
    point = intersect_ground(position_enu, ray, ground_up, max_range)
    return None if np.isnan(point).any() else point


def pointing_angles(
    pose: AircraftPose, position_enu: ArrayLike, target_enu: ArrayLike, *, stabilised: bool = True
) -> Gimbal:
    """The inverse: pan & tilt that put ``target_enu`` on the optical axis, seen from ``position_enu``.

    Pan is in [-180, 180], tilt in [-90, 90]. Straight below (pan undefined) gives pan 0, tilt -90.
    ``stabilised`` must match the mount (``CameraModel.stabilised``).
    """
    los_enu = np.asarray(target_enu, dtype=np.float64) - np.asarray(position_enu, dtype=np.float64)
    if not np.any(los_enu):
        raise ValueError("target coincides with the camera position")
    m = enu_from_mount(pose, stabilised).T @ los_enu  # line of sight in the mount frame (FRD-like)
    pan = math.degrees(math.atan2(m[1], m[0]))
    tilt = math.degrees(math.atan2(-m[2], math.hypot(m[0], m[1])))
    return Gimbal(pan=wrap_deg(pan), tilt=max(-90.0, min(90.0, tilt)))


def enu_to_pixel(
    camera: CameraModel, pose: AircraftPose, gimbal: Gimbal, position_enu: ArrayLike, points_enu: ArrayLike
) -> NDArray[np.float64]:
    """Project ENU points (..., 3) to pixels (..., 2); NaN for points behind the camera."""
    rel = np.asarray(points_enu, dtype=np.float64) - np.asarray(position_enu, dtype=np.float64)
    optical = rel @ enu_from_optical(pose, gimbal, camera.stabilised)  # row vectors: (R.T @ p).T == p.T @ R
    return camera.project(optical)
