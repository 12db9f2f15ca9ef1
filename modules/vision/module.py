"""The vision module process: camera frames + robot telemetry → target point (pan & tilt) and a short path.

Thin on purpose: every decision is in :class:`~modules.vision.pipeline.VisionPipeline`. This process reads the
aircraft pose and the pan & tilt angles from the telemetry module, grabs a frame at the camera rate, runs the
pipeline, and publishes only when the pipeline says so (target FOUND and geolocated):

| slot | dir | kind | struct |
| --- | --- | --- | --- |
| ``telemetry`` | in (peer ``telemetry``) | unsafe state | :class:`bbcs.contracts.robot.RobotTelemetry` |
| ``target`` | out | unsafe state | :class:`bbcs.contracts.pan_tilt.DatosPT` (mode 1 target point + pointing angles) |
| ``path`` | out | safe stream | :class:`bbcs.contracts.path_follower.DatosSegCam` (short path over the target) |
| ``status`` | out | unsafe state | :class:`VisionStatus` (track state, confidence, counters, lost-target state) |
| ``error`` | out | safe state | :class:`bbcs.contracts.errors.ErrorReport` |

Parameters (manifest ``params`` or ``--param``): ``camera`` = ``sim`` (default) | ``folder:PATH`` |
``v4l2:DEVICE``; ``rate`` frames/s (10); ``width``, ``height`` pixels (640 × 480) and ``hfov`` degrees (60): the
camera's image and horizontal field of view (a simulated camera renders that image; a real one must deliver it);
``ground_alt`` metres (0); ``path_period`` s between paths (2);
simulated scene: ``target_east``, ``target_north`` (m from the first telemetry position), ``target_ve``,
``target_vn`` (m/s), ``target_radius`` (m), ``noise`` (grey levels).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

import msgspec

from bbcs import InputSlot, Kind, Module, OutputSlot, Safety, load_params, struct_param_errors
from bbcs.contracts.error_codes import VisionErrorCode
from bbcs.contracts.errors import ErrorReport
from bbcs.contracts.pan_tilt import DatosPT
from bbcs.contracts.path_follower import DatoPuntoSegCam, DatosSegCam
from bbcs.contracts.robot import RobotTelemetry

if TYPE_CHECKING:  # the vision parts (numpy) are imported where they are used: the Module Manager imports this
    # class to check the manifest, and numpy is ~0.1 s of its start-up
    from modules.vision.pipeline import VisionResult
    from modules.vision.pose import AircraftPose, Gimbal
    from modules.vision.source import CameraSource


class VisionParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The vision module's manifest ``params``: checked by ``cromat launch --check`` and loaded by the module
    through the same :func:`bbcs.params.load_params`."""

    camera: Annotated[str, msgspec.Meta(pattern=r"^(sim|folder:.+|v4l2:.*)$")] = "sim"
    """``sim`` | ``folder:PATH`` | ``v4l2:DEVICE``."""
    rate: Annotated[float, msgspec.Meta(ge=0.1, le=200)] = 10.0
    """Frames per second."""
    width: Annotated[int, msgspec.Meta(ge=16, le=8192)] = 640
    """Image width, pixels."""
    height: Annotated[int, msgspec.Meta(ge=16, le=8192)] = 480
    """Image height, pixels."""
    hfov: Annotated[float, msgspec.Meta(ge=1.0, le=170.0)] = 60.0
    """Horizontal field of view across the image width, degrees."""
    ground_alt: float = 0.0
    """Ground altitude, metres."""
    path_period: Annotated[float, msgspec.Meta(gt=0)] = 2.0
    """Seconds between short paths."""
    target_east: float = 20.0
    target_north: float = 0.0
    target_ve: float = 0.0
    target_vn: float = 0.0
    target_radius: Annotated[float, msgspec.Meta(gt=0)] = 2.0
    noise: Annotated[float, msgspec.Meta(ge=0)] = 2.0
    """Grey levels of the simulated camera's noise."""


class VisionStatus(msgspec.Struct, frozen=True, kw_only=True):
    """What the vision module is doing, published every frame."""

    state: str
    """``lost``, ``tentative`` or ``found``; ``waiting`` until the first telemetry arrives."""
    confidence: float = 0.0
    frames: int = 0
    detections: int = 0
    published: int = 0
    target_lat: float | None = None
    target_lon: float | None = None
    frame_stamp: float = 0.0


def pose_and_gimbal(t: RobotTelemetry) -> tuple[AircraftPose, Gimbal] | None:
    """The pose and pan & tilt angles a frame needs, or None while telemetry lacks them."""
    if t.position is None or t.pan_deg is None or t.tilt_deg is None:
        return None
    from modules.vision.pose import AircraftPose, Gimbal

    att = t.attitude
    yaw = att.yaw if att is not None else (t.heading_deg or 0.0)
    pose = AircraftPose(t.position.lat, t.position.lon, t.position.alt,
                        att.roll if att else 0.0, att.pitch if att else 0.0, yaw)
    return pose, Gimbal(pan=t.pan_deg, tilt=t.tilt_deg)


def target_datum(result: VisionResult) -> DatosPT:
    """DATOS_PT for the pan & tilt's mode 1 (target point), with the pointing angles for mode 0."""
    fix = result.target
    assert fix is not None
    return DatosPT(ref_pan=fix.pointing.pan, ref_tilt=fix.pointing.tilt, latitud=fix.lat, longitud=fix.lon,
                   altura=fix.alt)


def path_datum(result: VisionResult) -> DatosSegCam:
    """The trajectory as a DATOS stream message (n_points + points)."""
    assert result.trajectory is not None
    points = [DatoPuntoSegCam(latitud=float(lat), longitud=float(lon), altura=float(alt))
              for lat, lon, alt in result.trajectory]
    return DatosSegCam(n_points=len(points), puntos=points)


class Vision(Module):
    name = "vision"
    slots = (
        InputSlot("telemetry", RobotTelemetry, safety=Safety.UNSAFE, peer="telemetry"),
        OutputSlot("target", DatosPT, safety=Safety.UNSAFE, priority="data_low"),
        OutputSlot("path", DatosSegCam, kind=Kind.STREAM),
        OutputSlot("status", VisionStatus, safety=Safety.UNSAFE, priority="data_low"),
        OutputSlot("error", ErrorReport),
    )
    error_slot = "error"

    params_type = VisionParams
    runtime_params: frozenset[str] = frozenset()
    """None at run time (``cromat param``): the camera and detector are set up when it starts."""

    @staticmethod
    def param_errors(params: dict[str, str]) -> list[tuple[str, str]]:
        """Every problem of the manifest's vision ``params`` (``cromat launch --check``, with file:line)."""
        return struct_param_errors(VisionParams, params, what="vision")

    def __init__(self, context) -> None:  # type: ignore[no-untyped-def]
        super().__init__(context)
        self.cfg = load_params(VisionParams, context.params, what="vision")  # ParamError: exit 78, no restart
        self.rate = self.cfg.rate
        self.tick_period = 1.0 / self.rate
        self.ground_alt = self.cfg.ground_alt
        self.path_period = self.cfg.path_period
        self.camera_spec = self.cfg.camera
        from modules.vision.geometry import CameraModel
        from modules.vision.pipeline import VisionConfig, VisionPipeline

        camera = CameraModel(width=self.cfg.width, height=self.cfg.height, hfov_deg=self.cfg.hfov)
        self.pipeline = VisionPipeline(VisionConfig(camera=camera, ground_alt=self.ground_alt))
        self.latest: RobotTelemetry | None = None
        self.source: CameraSource | None = None
        self._last_path = 0.0
        self._camera_failed = False
        self._simulated = False

    def _open_source(self, first: RobotTelemetry) -> CameraSource:
        kind, _, arg = self.camera_spec.partition(":")
        if kind == "folder":
            from modules.vision.folder_camera import FolderCamera
            return FolderCamera(arg, rate_hz=self.rate, loop=True)
        if kind == "v4l2":
            from modules.vision.v4l2_camera import V4L2Camera
            return V4L2Camera(arg or 0)
        if kind != "sim":
            raise ValueError(f"vision: unknown camera {self.camera_spec!r} (sim | folder:PATH | v4l2:DEVICE)")
        assert first.position is not None
        from modules.vision.geodesy import LocalFrame
        from modules.vision.scene import LinearTarget
        from modules.vision.sim_camera import SimulatedCamera

        p = self.cfg
        self._simulated = True
        world = LocalFrame(first.position.lat, first.position.lon, self.ground_alt)
        target = LinearTarget(start=(p.target_east, p.target_north), velocity=(p.target_ve, p.target_vn),
                              radius_m=p.target_radius)
        return SimulatedCamera(world, camera=self.pipeline.config.camera, ground_alt=self.ground_alt,
                               targets=[target], noise_sigma=p.noise,
                               clock=self.bbcs_clock.monotonic)  # the scene moves in the robot's time

    def on_telemetry(self, value: RobotTelemetry) -> None:
        self.latest = value

    def on_tick(self) -> None:
        telemetry = self.latest
        state = None if telemetry is None else pose_and_gimbal(telemetry)
        if state is None:
            self.publish("status", VisionStatus(state="waiting"))
            return
        pose, gimbal = state
        if self.source is None:
            self.source = self._open_source(telemetry)
        if self._simulated:  # a simulated camera renders what the aircraft's pose and gimbal show
            self.source.set_state(pose, gimbal)  # type: ignore[attr-defined]
        try:
            frame = self.source.read()
        except Exception as exc:
            if not self._camera_failed:
                self.report_error(VisionErrorCode.CAMERA_FAILED, f"camera {self.camera_spec}: {exc}")
            self._camera_failed = True
            return
        if frame is None:
            return
        self._camera_failed = False
        try:
            result = self.pipeline.process(frame, pose, gimbal)
        except ValueError as exc:
            self.report_error(VisionErrorCode.BAD_TELEMETRY, f"frame {frame.seq} skipped: {exc}")
            return
        if result.publish:
            self.publish("target", target_datum(result))
            now = self.bbcs_clock.monotonic()
            if now - self._last_path >= self.path_period:
                self.publish("path", path_datum(result))
                self._last_path = now
        det = result.detection
        fix = result.target
        self.publish("status", VisionStatus(
            state=result.state.value, confidence=det.confidence if det else 0.0, frames=self.pipeline.frames,
            detections=self.pipeline.detections, published=self.pipeline.published,
            target_lat=fix.lat if fix else None, target_lon=fix.lon if fix else None, frame_stamp=frame.timestamp))

    def on_stop(self) -> None:
        if self.source is not None:
            self.source.close()
