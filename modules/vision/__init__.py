"""Vision module core: camera sources, target detection, geolocation, tracking state and trajectories.

Pure, bus-independent parts; the bus process calls ``VisionPipeline.process`` per frame. See docs/vision.md
for the frames, conventions and bounds.
"""

from .detect import Blob, Detection, DetectorConfig, detect, find_blobs, score_map
from .folder_camera import FolderCamera, load_image
from .geodesy import LocalFrame
from .geometry import CameraModel, enu_to_pixel, intersect_ground, pixel_to_enu, pointing_angles
from .pipeline import TargetFix, VisionConfig, VisionPipeline, VisionResult
from .pnm import PnmError, encode_pnm, parse_pnm
from .pose import AircraftPose, Gimbal
from .scene import CircularTarget, GroundTexture, LinearTarget
from .sim_camera import SimulatedCamera
from .source import CameraSource, Frame
from .tracker import TargetTracker, TrackerConfig, TrackState
from .trajectory import TrajectoryConfig, plan_trajectory
from .v4l2_camera import CameraUnavailableError, V4L2Camera

__all__ = [
    "AircraftPose",
    "Blob",
    "CameraModel",
    "CameraSource",
    "CameraUnavailableError",
    "CircularTarget",
    "Detection",
    "DetectorConfig",
    "FolderCamera",
    "Frame",
    "Gimbal",
    "GroundTexture",
    "LinearTarget",
    "LocalFrame",
    "PnmError",
    "SimulatedCamera",
    "TargetFix",
    "TargetTracker",
    "TrackState",
    "TrackerConfig",
    "TrajectoryConfig",
    "V4L2Camera",
    "VisionConfig",
    "VisionPipeline",
    "VisionResult",
    "detect",
    "encode_pnm",
    "enu_to_pixel",
    "find_blobs",
    "intersect_ground",
    "load_image",
    "parse_pnm",
    "pixel_to_enu",
    "plan_trajectory",
    "pointing_angles",
    "score_map",
]
