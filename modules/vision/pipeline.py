"""VisionPipeline: frame + aircraft pose + pan & tilt -> detection, tracking state, target LLA, trajectory.

Everything the vision process decides lives here so that the bus process only reads frames and telemetry,
calls ``process`` and publishes what the result says (``publish``), keeping it thin.
Geolocation uses a local level frame centred under the aircraft for each frame, so no fixed reference is
needed and the linearisation error stays small (see geodesy).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .detect import Detection, DetectorConfig, detect
from .geodesy import LocalFrame
from .geometry import CameraModel, pixel_to_enu, pointing_angles
from .pose import AircraftPose, Gimbal
from .source import Frame
from .tracker import TargetTracker, TrackerConfig, TrackState
from .trajectory import TrajectoryConfig, plan_trajectory


@dataclass(frozen=True)
class VisionConfig:
    """Camera model, flat-ground altitude (metres, same datum as the aircraft altitude) and stage settings."""

    camera: CameraModel = field(default_factory=CameraModel)
    ground_alt: float = 0.0
    max_range_m: float = 2000.0
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)

    def __post_init__(self) -> None:
        if not math.isfinite(self.ground_alt):
            raise ValueError(f"ground_alt {self.ground_alt!r} is not finite")
        if not self.max_range_m > 0.0:
            raise ValueError(f"max_range_m {self.max_range_m!r} must be > 0")


@dataclass(frozen=True, slots=True)
class TargetFix:
    """Geolocated target: WGS84 lat/lon (degrees), altitude (metres), slant range and the pan & tilt that
    point the camera at it from the current pose (what DATOS_PT carries)."""

    lat: float
    lon: float
    alt: float
    range_m: float
    pointing: Gimbal


@dataclass(frozen=True, slots=True)
class VisionResult:
    """Outcome of one frame. ``publish`` is True only when the track is FOUND and this frame has a
    detection that passed the tracker's threshold and could be geolocated; then ``target`` and
    ``trajectory`` are what to send."""

    seq: int
    timestamp: float
    detection: Detection | None
    state: TrackState
    target: TargetFix | None
    trajectory: NDArray[np.float64] | None
    publish: bool


class VisionPipeline:
    """Stateful only through the tracker; counters say how many frames ended where."""

    def __init__(self, config: VisionConfig | None = None) -> None:
        self.config = config if config is not None else VisionConfig()
        self.tracker = TargetTracker(self.config.tracker)
        self.frames = 0
        self.detections = 0
        self.geolocation_failures = 0
        self.published = 0

    def _check_frame(self, frame: Frame) -> None:
        cam = self.config.camera
        if (frame.width, frame.height) != (cam.width, cam.height):
            raise ValueError(
                f"frame {frame.seq} is {frame.width}x{frame.height}, camera model is {cam.width}x{cam.height}"
            )

    def geolocate(self, detection: Detection, pose: AircraftPose, gimbal: Gimbal) -> TargetFix | None:
        """Ground point under the detection's centroid, or None when its ray misses the ground in range."""
        cfg = self.config
        frame = LocalFrame(pose.lat, pose.lon, 0.0)
        position = np.array([0.0, 0.0, pose.alt])
        point = pixel_to_enu(
            cfg.camera, pose, gimbal, position, (detection.x, detection.y), cfg.ground_alt, cfg.max_range_m
        )
        if point is None:
            return None
        lat, lon, alt = frame.to_lla(point)
        return TargetFix(
            lat=float(lat),
            lon=float(lon),
            alt=float(alt),
            range_m=float(np.linalg.norm(point - position)),
            pointing=pointing_angles(pose, position, point, stabilised=cfg.camera.stabilised),
        )

    def process(self, frame: Frame, pose: AircraftPose, gimbal: Gimbal) -> VisionResult:
        """Run detection, geolocation, tracking and planning for one frame."""
        self._check_frame(frame)
        self.frames += 1
        detection = detect(frame.image, self.config.detector)
        target = None
        if detection is not None:
            self.detections += 1
            target = self.geolocate(detection, pose, gimbal)
            if target is None:
                self.geolocation_failures += 1
        # A detection that cannot be geolocated is of no use to anyone downstream: it counts as a miss.
        state = self.tracker.update(detection.confidence if target is not None else None, frame.timestamp)
        publish = state is TrackState.FOUND and self.tracker.hit and target is not None
        trajectory = None
        if publish:
            assert target is not None
            trajectory = plan_trajectory(pose, (target.lat, target.lon, target.alt), self.config.trajectory)
            self.published += 1
        return VisionResult(
            seq=frame.seq,
            timestamp=frame.timestamp,
            detection=detection,
            state=state,
            target=target,
            trajectory=trajectory,
            publish=publish,
        )
