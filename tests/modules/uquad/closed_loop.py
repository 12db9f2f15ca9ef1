"""In-process closed loop for tests: simulator physics + sensors, FlightCore, the driver's logic (no transports)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from modules.uquad.calibration import load_calibration
from modules.uquad.config import load_config
from modules.uquad.core import FlightCore
from modules.uquad.geo import Home
from modules.uquad.gps import LocalGps
from modules.uquad.motor_driver import DriverLogic
from modules.uquad.sim.quad import QuadSim

ROOT = Path(__file__).resolve().parents[3]


class ClosedLoop:
    def __init__(self, controller_mode: str = "hover", seed: int = 3, gps: bool = True) -> None:
        cfg = load_config(ROOT / "bbcs_conf" / "uquad1.conf")
        cal = load_calibration(cfg.imu_calib_file)
        self.home = Home(cfg.home_lat, cfg.home_lon, cfg.home_alt)
        self.sim = QuadSim(cfg.quad, cal, self.home, seed=seed)
        self.core = FlightCore(cfg, cal, controller_mode)
        v = cfg.values
        self.driver = DriverLogic(v.MOTOR_MIN, v.MOTOR_MAX, v.MOTOR_RAMP_S, v.MOTOR_CMD_TIMEOUT)
        self.gps = gps
        self.t = 0.0
        self.ticks = 0
        self.trace: list[tuple[float, np.ndarray, np.ndarray]] = []
        """(t, true state, estimated state) every 0.1 s."""

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / 0.01)):
            for _ in range(5):
                self.sim.step(0.002)
            self.ticks += 1
            self.t = self.sim.t = self.ticks * 0.01
            cmd = self.core.on_imu(self.sim.imu_frame(), self.t)
            if cmd is not None:
                self.driver.on_command(self.t, tuple(cmd))
            self.sim.command(self.driver.output(self.t))
            if self.ticks % 20 == 0:
                if self.gps:
                    f = self.sim.gps_fix()
                    e, n, u = self.home.to_local(f.lat, f.lon, f.alt)
                    self.core.on_gps(LocalGps(e, n, u, f.ve, f.vn))
            if self.ticks % 10 == 0:
                self.trace.append((self.t, self.sim.x.copy(), self.core.state()))
