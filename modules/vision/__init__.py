"""Vision module core: camera sources, target detection, geolocation, tracking state and trajectories.

Pure, bus-independent parts; the bus process calls ``VisionPipeline.process`` per frame. See docs/vision.md
for the frames, conventions and bounds.
"""

from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "AircraftPose": "pose",
    "Blob": "detect",
    "CameraModel": "geometry",
    "CameraSource": "source",
    "CameraUnavailableError": "v4l2_camera",
    "CircularTarget": "scene",
    "Detection": "detect",
    "DetectorConfig": "detect",
    "FolderCamera": "folder_camera",
    "Frame": "source",
    "Gimbal": "pose",
    "GroundTexture": "scene",
    "LinearTarget": "scene",
    "LocalFrame": "geodesy",
    "PnmError": "pnm",
    "SimulatedCamera": "sim_camera",
    "TargetFix": "pipeline",
    "TargetTracker": "tracker",
    "TrackState": "tracker",
    "TrackerConfig": "tracker",
    "TrajectoryConfig": "trajectory",
    "V4L2Camera": "v4l2_camera",
    "VisionConfig": "pipeline",
    "VisionPipeline": "pipeline",
    "VisionResult": "pipeline",
    "detect": "detect",
    "encode_pnm": "pnm",
    "enu_to_pixel": "geometry",
    "find_blobs": "detect",
    "intersect_ground": "geometry",
    "load_image": "folder_camera",
    "parse_pnm": "pnm",
    "pixel_to_enu": "geometry",
    "plan_trajectory": "trajectory",
    "pointing_angles": "geometry",
    "score_map": "detect",
}
"""Which submodule each name comes from: imported on first use (PEP 562), so that importing one submodule (the
Module Manager imports ``modules.vision.module`` to check a manifest) does not import numpy and every camera."""


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = sorted(_WHERE)
