"""Simulated gimballed camera: renders the ground texture and targets seen from the aircraft pose.

Rendering inverse-maps every pixel: its optical ray is rotated into ENU and intersected with the flat ground
(vectorised over the whole image), the texture is evaluated at the hit points, and target discs are painted
where a hit point lies inside a disc. Rays that miss the ground get the sky colour. The caller sets the pose
and the pan & tilt angles (``set_state``), e.g. from telemetry.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .geodesy import LocalFrame
from .geometry import CameraModel, enu_from_optical
from .pose import AircraftPose, Gimbal
from .scene import RGB, GroundTexture, Target
from .source import CameraSource, Frame

#: Luminance weights (ITU-R BT.601) used for grey frames.
LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)


class GroundView(NamedTuple):
    """What one camera pose sees of the ground: each pixel's hit point (east, north), whether its ray hits the
    ground, and the image without targets (texture, and sky where the ray misses)."""

    east: NDArray[np.float32]
    north: NDArray[np.float32]
    hits: NDArray[np.bool_]
    rgb: NDArray[np.float32]


def ground_view(
    camera: CameraModel,
    rotation_enu_optical: NDArray[np.float64],
    position_enu: ArrayLike,
    ground_up: float,
    texture: GroundTexture,
    sky: RGB = (150, 190, 230),
) -> GroundView:
    """The ground as one camera orientation/position sees it. The ENU ray of pixel (u, v) is
    R @ (x[u], y[v], 1) = x[u]·R[:, 0] + y[v]·R[:, 1] + R[:, 2], built by broadcasting."""
    x, y = camera.grid_axes()
    r = rotation_enu_optical.astype(np.float32)
    col, row = x[None, :], y[:, None]
    dz = col * r[2, 0] + row * r[2, 1] + r[2, 2]
    pos = np.asarray(position_enu, dtype=np.float64)
    height = np.float32(pos[2] - ground_up)
    hits = (dz < 0.0) & (height > 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(hits, -height / dz, np.float32(0.0))
    east = np.float32(pos[0]) + t * (col * r[0, 0] + row * r[0, 1] + r[0, 2])
    north = np.float32(pos[1]) + t * (col * r[1, 0] + row * r[1, 1] + r[1, 2])
    rgb = texture.colour(east, north)
    rgb[~hits] = np.asarray(sky, np.float32)
    return GroundView(east, north, hits, rgb)


def paint_targets(view: GroundView, targets: Sequence[tuple[float, float, float, RGB]]) -> NDArray[np.float32]:
    """A new float32 RGB image (H, W, 3): ``view`` with the ``targets``, (east, north, radius_m, colour) discs lying
    on the ground plane, painted over the ground."""
    rgb = view.rgb.copy()
    for te, tn, radius, colour in targets:
        inside = view.hits & ((view.east - np.float32(te)) ** 2 + (view.north - np.float32(tn)) ** 2
                              <= np.float32(radius) ** 2)
        rgb[inside] = np.asarray(colour, np.float32)
    return rgb


class SimulatedCamera(CameraSource):
    """Renders frames of a synthetic world defined in the ENU frame ``world`` (ground at ``ground_alt``).

    Targets move with scene time ``t = clock() - epoch`` (epoch defaults to the clock at construction).
    ``noise_sigma`` adds Gaussian sensor noise (grey levels), reproducible from ``seed``.
    ``grey=True`` returns HxW luminance frames instead of RGB.
    """

    def __init__(
        self,
        world: LocalFrame,
        *,
        camera: CameraModel | None = None,
        ground_alt: float = 0.0,
        targets: Sequence[Target] = (),
        texture: GroundTexture | None = None,
        noise_sigma: float = 0.0,
        seed: int = 0,
        grey: bool = False,
        clock: Callable[[], float] = time.monotonic,
        epoch: float | None = None,
    ) -> None:
        super().__init__()
        if not (math.isfinite(noise_sigma) and noise_sigma >= 0.0):
            raise ValueError(f"noise_sigma {noise_sigma!r} must be >= 0")
        self.world = world
        self.camera = camera if camera is not None else CameraModel()
        self.ground_alt = float(ground_alt)
        self.targets = tuple(targets)
        self.texture = texture if texture is not None else GroundTexture(seed=seed)
        self.noise_sigma = float(noise_sigma)
        self.grey = grey
        self._rng = np.random.default_rng(seed)
        self._noise_bank: NDArray[np.float32] | None = None
        self._clock = clock
        self.epoch = clock() if epoch is None else float(epoch)
        self._seq = 0
        self._pose: AircraftPose | None = None
        self._gimbal: Gimbal | None = None
        self._view_key: tuple[object, ...] | None = None
        self._view: GroundView | None = None

    def set_state(self, pose: AircraftPose, gimbal: Gimbal) -> None:
        """Aircraft pose (LLA + attitude) and pan & tilt for the next frames."""
        self._pose = pose
        self._gimbal = gimbal

    def set_state_enu(
        self, position_enu: ArrayLike, gimbal: Gimbal, roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0
    ) -> None:
        """Same as ``set_state`` with the position given in the world ENU frame (metres)."""
        lat, lon, alt = self.world.to_lla(position_enu)
        self.set_state(AircraftPose(float(lat), float(lon), float(alt), roll, pitch, yaw), gimbal)

    @property
    def pose(self) -> AircraftPose | None:
        return self._pose

    @property
    def gimbal(self) -> Gimbal | None:
        return self._gimbal

    def scene_time(self, timestamp: float) -> float:
        """Scene time of a frame timestamp."""
        return timestamp - self.epoch

    def targets_enu(self, timestamp: float) -> NDArray[np.float64]:
        """True target centres (n, 3) in world ENU at a frame timestamp (on the ground plane)."""
        t = self.scene_time(timestamp)
        up = self.ground_alt - self.world.alt0
        return np.array([(*tg.position(t), up) for tg in self.targets], dtype=np.float64).reshape(-1, 3)

    def render(self, timestamp: float) -> np.ndarray:
        """The uint8 image for the current state at ``timestamp``; requires ``set_state`` first."""
        if self._pose is None or self._gimbal is None:
            raise RuntimeError("SimulatedCamera.render needs set_state() first")
        position = self.world.to_enu(self._pose.lat, self._pose.lon, self._pose.alt)
        t = self.scene_time(timestamp)
        discs = [(*tg.position(t), tg.radius_m, tg.colour) for tg in self.targets]
        rgb = paint_targets(self._ground(position), discs)
        img = rgb @ LUMA if self.grey else rgb
        if self.noise_sigma > 0.0:
            img = img + self._noise(img.shape)
        return np.clip(img + np.float32(0.5), 0.0, 255.0).astype(np.uint8)

    def _ground(self, position: NDArray[np.float64]) -> GroundView:
        """The ground seen from the current pose, kept while the pose and gimbal stay the same (an aircraft on the
        ground or holding still sees the same ground every frame: only the targets move, and they are painted
        anew on each frame; rendering the ground was nine tenths of a frame's cost)."""
        assert self._pose is not None and self._gimbal is not None
        key = (self._pose, self._gimbal, position.tobytes())
        if self._view is None or key != self._view_key:
            self._view = ground_view(self.camera, enu_from_optical(self._pose, self._gimbal, self.camera.stabilised),
                                     position, self.ground_alt - self.world.alt0, self.texture)
            self._view_key = key
        return self._view

    def _noise(self, shape: tuple[int, ...]) -> NDArray[np.float32]:
        """Gaussian sensor noise for one frame: a window at a random offset into a bank of twice a frame's
        samples, drawn once. Drawing a frame's samples anew cost more than rendering it (every frame of every
        simulated flight); each pixel's noise is still Gaussian and the frames' windows differ."""
        size = math.prod(shape)
        if self._noise_bank is None or self._noise_bank.size != 2 * size:
            self._noise_bank = self._rng.standard_normal(2 * size, dtype=np.float32) * np.float32(self.noise_sigma)
        start = int(self._rng.integers(0, size + 1))
        return self._noise_bank[start:start + size].reshape(shape)

    def read(self) -> Frame | None:
        """Render a frame at the current clock time; None before the first ``set_state`` or after close."""
        if self._closed or self._pose is None:
            return None
        now = self._clock()
        frame = Frame(image=self.render(now), timestamp=now, seq=self._seq)
        self._seq += 1
        return frame
