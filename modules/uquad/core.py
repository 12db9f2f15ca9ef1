"""The uQuad's main loop body (the seed's ``main``), without I/O: IMU frames and GPS samples in, motor speeds out.

Per IMU frame: start calibration (until done), conversion, Kalman prediction with the measured period and
corrections; every CONTROL_EVERY frames the path planner and the controller. While the motors spin up (the
driver's ramp) the set point is frozen and the integral is held at zero, so nothing winds up on the ground.
``now`` is given by the caller (the wall clock on the robot: the seed measures Ts from elapsed time).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from control.laws import AntiWindup
from modules.uquad import model
from modules.uquad.calibration import (
    ImuCalibration,
    ImuData,
    MotionDuringCalibration,
    StartCalibration,
    StartCalibrator,
    convert,
)
from modules.uquad.config import Config, load_matrix
from modules.uquad.controller import Controller, SetPoint
from modules.uquad.fir import RawQueue, frame_values, values_frame
from modules.uquad.gps import LocalGps
from modules.uquad.imu_protocol import ImuFrame
from modules.uquad.kalman import Kalman
from modules.uquad.planner import Mode, Planner, PlannerConfig
from modules.uquad.upset import FallWatch, TumbleCut


@dataclass
class CoreStats:
    frames: int = 0
    control_actions: int = 0
    calibration_refusals: int = 0
    tumble_cuts: int = 0
    """Times the motors were cut because the estimate showed the quadrotor tumbling (upset.py)."""
    gps_updates: int = 0
    last_ts: float = 0.0
    """The last measured control period (s)."""
    errors: list[str] = field(default_factory=list)


class FlightCore:
    def __init__(self, cfg: Config, calib: ImuCalibration, controller_mode: str = "hover") -> None:
        v = cfg.values
        self.cfg = cfg
        self.calib = calib
        self.calibrator = StartCalibrator(calib, v.IMU_CALIB_SAMPLES, v.IMU_CALIB_GYRO_STD_MAX,
                                          v.IMU_CALIB_ACC_STD_MAX)
        self.start: StartCalibration | None = None
        self.kalman = Kalman(g=cfg.quad.g)
        aw = cfg.anti_windup
        self.controller = Controller(
            cfg.quad, load_matrix(cfg.file(v.K_PROP_FILE), (4, 12)), load_matrix(cfg.file(v.K_INT_FILE), (4, 4)),
            AntiWindup(th_dist=np.array(aw.th_dist), th_max=np.array(aw.th_max), accum_high=np.array(aw.th_accum)),
            cfg.lqr, v.MOTOR_MIN, v.MOTOR_MAX, v.MAX_POS_ERR, controller_mode)
        self.planner = Planner(PlannerConfig(
            takeoff_height=v.TAKEOFF_HEIGHT_DEFAULT, waypoint_radius=v.WAYPOINT_RADIUS,
            waypoint_speed_max=v.WAYPOINT_SPEED_MAX, cruise_speed=v.CRUISE_SPEED, land_speed=v.LAND_SPEED,
            ground_height=v.GROUND_HEIGHT, max_height=v.MAX_HEIGHT, accel=v.SETPOINT_ACCEL))
        self.every = v.CONTROL_EVERY
        self.tumble = TumbleCut(v.CUT_TILT_DEG, v.CUT_TILT_S)
        self.fall = FallWatch()
        """After a tumble cut: falling until the IMU shows the quadrotor at rest (reported airborne till then)."""
        self.raw_queue = RawQueue(v.IMU_QUEUE_LEN, v.IMU_FIR) if v.IMU_FIR else None
        """The seed's FIR filter on the raw frames (off by default, as the seed flew): IMU_FIR in the .conf."""
        self.spinup_s = v.MOTOR_RAMP_S + 0.3
        self.hover_speed = cfg.quad.hover_speed
        self.stats = CoreStats()
        self.data: ImuData | None = None
        self.gyro = np.zeros(3)
        self._last_kalman: float | None = None
        self._last_control: float | None = None
        self._since_control = 0
        self._motors_on_at: float | None = None
        self.last_command = np.zeros(4)

    @property
    def calibrated(self) -> bool:
        return self.start is not None

    def state(self) -> np.ndarray:
        """The estimated state in the model's order (x y z ψ φ θ vx vy vz p q r)."""
        k = self.kalman
        return np.concatenate([k.position, k.euler, k.velocity, self.gyro])

    def set_mode(self, mode: Mode) -> None:
        k = self.kalman
        self.planner.set_mode(mode, k.position.copy(), float(k.euler[2]), k.velocity.copy())

    def set_waypoints(self, points: list[np.ndarray]) -> None:
        self.planner.set_waypoints(points)

    def on_gps(self, gps: LocalGps) -> None:
        if self.calibrated:
            self.kalman.update_gps(gps.east, gps.north, gps.ve, gps.vn)
            self.stats.gps_updates += 1

    def on_imu(self, frame: ImuFrame, now: float) -> np.ndarray | None:
        """Motor speeds to send now (zeros = stop), or None when this frame brings no control action."""
        return self.on_frames((frame,), now)

    def on_frames(self, frames: Sequence[ImuFrame], now: float) -> np.ndarray | None:
        """Every frame read in one go (the seed's main: read until the IMU has nothing more, then convert and
        advance). All of them count for the start calibration, the raw queue (FIR) and the sample count; the
        estimator and the controller run once, with the period measured from ``now``, on the batch's mean (the
        conversion is linear in the raw counts, so the mean rates integrate the whole gap, where the newest
        sample alone would not) or on the filtered frame when the FIR is on. Motor speeds to send now (zeros =
        stop), or None when no control action is due."""
        if not frames:
            return None
        self.stats.frames += len(frames)
        if self.start is None:
            for frame in frames:
                try:
                    self.start = self.calibrator.add(frame)
                except MotionDuringCalibration as exc:
                    self.stats.calibration_refusals += 1
                    self.stats.errors.append(str(exc))
                    continue
                if self.start is not None:
                    data = convert(frame, self.calib, self.start)
                    self.kalman.init(data.euler, data.altitude_m)
                    self._last_kalman = now
                    break
            return None
        frame = frames[-1] if len(frames) == 1 else batch_mean(frames)
        if self.raw_queue is not None:
            for f in frames:
                self.raw_queue.push(f)
            frame = self.raw_queue.filtered() or frame
        data = convert(frame, self.calib, self.start)
        self.data = data
        self.gyro = data.gyro
        dt = now - (self._last_kalman if self._last_kalman is not None else now)
        self._last_kalman = now
        k = self.kalman
        k.predict(data.acc, data.gyro, dt)
        k.update_attitude(data.euler, data.acc_norm_dev, data.mag_norm_dev, flying=self.planner.airborne)
        k.update_altitude(data.altitude_m)
        self.fall.update(now, float(np.linalg.norm(data.gyro)), data.acc_norm_dev)
        if not self.planner.airborne and not self.fall.falling:  # motors cut in the air: not still, falling
            k.update_still()
        if self.tumble.update(now, float(k.euler[0]), float(k.euler[1]), self.planner.airborne):
            self.planner.set_mode(Mode.IDLE, k.position.copy(), float(k.euler[2]))  # motors off, now
            self.stats.tumble_cuts += 1
            self.fall.cut()
            self.stats.errors.append(self.tumble.reason)
            self.controller.reset()
            self._motors_on_at = None
            self.last_command = np.zeros(4)
            return self.last_command
        self._since_control += len(frames)
        if self._since_control < self.every:
            return None
        self._since_control = 0
        return self._control(now)

    def _control(self, now: float) -> np.ndarray:
        ts = now - self._last_control if self._last_control is not None else 0.01 * self.every
        self._last_control = now
        self.stats.last_ts = ts
        self.stats.control_actions += 1
        if not self.planner.airborne:
            self._motors_on_at = None
            self.controller.reset()
            self.last_command = np.zeros(4)
            return self.last_command
        if self._motors_on_at is None:
            self._motors_on_at = now
        if now - self._motors_on_at < self.spinup_s:  # the driver's ramp: hold the set point, no integral
            self.controller.reset()
            self.last_command = np.full(4, self.controller.min_speed)
            return self.last_command
        out = self.planner.step(now, max(ts, 1e-4), self.kalman.position, self.kalman.velocity)
        if not out.motors_on:
            self.last_command = np.zeros(4)
            return self.last_command
        sp = SetPoint(self.planner.setpoint_state(out), np.full(4, self.hover_speed), out.new_target)
        self.last_command = self.controller.step(self.state(), sp, max(ts, 1e-4))
        return self.last_command


def batch_mean(frames: Sequence[ImuFrame]) -> ImuFrame:
    """The mean of several raw frames (counts as floats), the newest one's loop time."""
    return values_frame(np.mean([frame_values(f) for f in frames], axis=0), frames[-1].loop_us)


__all__ = ["FlightCore", "Mode", "batch_mean", "model"]
