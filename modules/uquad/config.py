"""The uQuad's robot .conf (``bbcs_conf/uquad1.conf``), typed; errors name the file and line (ConfError)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import msgspec
import numpy as np

from bbcs import ConfDocument, ConfError, load_conf
from modules.uquad.model import QuadParams


class AntiWindupConf(msgspec.Struct, frozen=True, kw_only=True):
    th_dist: list[float]
    th_max: list[float]
    th_accum: list[float]


class LqrConf(msgspec.Struct, frozen=True, kw_only=True):
    q: list[float]
    q_int: list[float]
    r: list[float]


class UquadConfig(msgspec.Struct, frozen=True, kw_only=True):
    ROBOT: str = "uquad"
    HOME_LAT: float
    HOME_LON: float
    HOME_ALT: float = 0.0
    IMU_PORT: str = ""
    IMU_BAUD: int = 115200
    IMU_MODE: Literal["binary", "ascii"] = "binary"
    IMU_CALIB_FILE: str
    IMU_CALIB_SAMPLES: int = 512
    IMU_CALIB_GYRO_STD_MAX: float = 0.02
    IMU_CALIB_ACC_STD_MAX: float = 0.3
    GPS_MODE: Literal["real", "zeros", "random", "none"] = "real"
    GPS_PORT: str = ""
    GPS_FAKE_RANGE: float = 5.0
    CONTROL_EVERY: int = 1
    K_PROP_FILE: str
    K_INT_FILE: str
    MAX_POS_ERR: float = 1.5
    IMU_FIR: list[float] = msgspec.field(default_factory=list)
    IMU_QUEUE_LEN: int = 16
    TAKEOFF_HEIGHT_DEFAULT: float = 3.0
    MAX_HEIGHT: float = 20.0
    WAYPOINT_RADIUS: float = 0.5
    WAYPOINT_SPEED_MAX: float = 0.5
    CRUISE_SPEED: float = 2.0
    LAND_SPEED: float = 0.5
    SETPOINT_ACCEL: Annotated[float, msgspec.Meta(gt=0.0, le=9.0)] = 2.0
    """m/s²: the set point speeds up, slows down and turns no harder (the tilt to follow it: atan(a / g))."""
    GROUND_HEIGHT: float = 0.15
    MOTOR_MIN: float = 300.0
    MOTOR_MAX: float = 750.0
    MOTOR_RAMP_S: float = 1.5
    MOTOR_SEND_PERIOD: float = 0.01
    MOTOR_CMD_TIMEOUT: float = 0.2
    MOTOR_ACK_TIMEOUT: float = 0.1
    MOTOR_ERROR_ACTION: Literal["land", "cut"] = "land"
    CUT_TILT_DEG: Annotated[float, msgspec.Meta(gt=0.0, le=180.0)] = 70.0
    """The estimate tilted beyond this (degrees) for CUT_TILT_S: tumbling, the motors are cut (upset.py)."""
    CUT_TILT_S: Annotated[float, msgspec.Meta(ge=0.0)] = 0.1
    LOG_DIR: str = "runs/uquad"


_GROUPS: tuple[tuple[str, str, type[msgspec.Struct], dict[str, int]], ...] = (
    ("QUAD", "model", QuadParams, {}),
    ("LQR", "weights", LqrConf, {"q": 12, "q_int": 4, "r": 4}),
    ("ANTI_WINDUP", "integral", AntiWindupConf, {"th_dist": 4, "th_max": 4, "th_accum": 4}),
)
"""The groups the uQuad reads: type, name, struct, and the keys that must hold a given number of values."""


def conf_errors(doc: ConfDocument) -> list[ConfError]:
    """Every mistake in the uQuad's part of a parsed .conf, each with file:line: for ``cromat conf check`` and
    ``cromat launch --check`` (``UquadModule.conf_errors``); empty when :class:`Config` would load it."""
    top_level = doc.errors_for(UquadConfig)
    errors = list(top_level)
    for gtype, gname, typ, lengths in _GROUPS:
        try:
            group = doc.group(gtype, gname)
        except ConfError as exc:
            errors.append(exc)
            continue
        found = group.errors_for(typ)
        errors += found
        if found:
            continue
        values = msgspec.structs.asdict(group.to_struct(typ))
        for key, n in lengths.items():
            if len(values[key]) != n:
                entry = group.entries[key]
                errors.append(ConfError(f"key {key!r} in group '{gtype}: {gname}' must have {n} values, has "
                                        f"{len(values[key])}", path=doc.path, line=entry.line, column=entry.column))
    if not top_level:
        v = doc.to_struct(UquadConfig)
        if not 0 < v.MOTOR_MIN < v.MOTOR_MAX:
            entry = doc.entries.get("MOTOR_MIN") or doc.entries.get("MOTOR_MAX")
            errors.append(ConfError("MOTOR_MIN must be > 0 and below MOTOR_MAX", path=doc.path,
                                    line=entry.line if entry else None))
        if v.IMU_FIR and v.IMU_QUEUE_LEN <= len(v.IMU_FIR):
            entry = doc.entries.get("IMU_QUEUE_LEN") or doc.entries["IMU_FIR"]
            errors.append(ConfError(f"IMU_QUEUE_LEN ({v.IMU_QUEUE_LEN}) must be longer than the IMU_FIR filter "
                                    f"({len(v.IMU_FIR)} coefficients)", path=doc.path, line=entry.line))
        if v.CONTROL_EVERY < 1:
            entry = doc.entries.get("CONTROL_EVERY")
            errors.append(ConfError("CONTROL_EVERY must be ≥ 1", path=doc.path, line=entry.line if entry else None))
    return sorted(errors, key=lambda e: (e.line or 0, e.column or 0))


class Config:
    """The parsed .conf plus its groups and the paths it names (resolved next to the file)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        doc = load_conf(path)
        self.doc = doc
        errors = conf_errors(doc)
        if errors:  # the first of what ``cromat conf check`` reports: the module and the check never disagree
            raise errors[0]
        self.values = doc.to_struct(UquadConfig)
        self.quad = doc.group("QUAD", "model").to_struct(QuadParams)
        self.lqr = doc.group("LQR", "weights").to_struct(LqrConf)
        self.anti_windup = doc.group("ANTI_WINDUP", "integral").to_struct(AntiWindupConf)

    @property
    def lqr_group(self):  # noqa: ANN201 - a ConfGroup
        return self.doc.group("LQR", "weights")

    @property
    def aw_group(self):  # noqa: ANN201
        return self.doc.group("ANTI_WINDUP", "integral")

    def file(self, name: str) -> Path:
        return (self.path.parent / name).resolve()

    # short names the code uses
    @property
    def home_lat(self) -> float:
        return self.values.HOME_LAT

    @property
    def home_lon(self) -> float:
        return self.values.HOME_LON

    @property
    def home_alt(self) -> float:
        return self.values.HOME_ALT

    @property
    def imu_mode(self) -> str:
        return self.values.IMU_MODE

    @property
    def imu_calib_file(self) -> Path:
        return self.file(self.values.IMU_CALIB_FILE)


def load_config(path: str | Path) -> Config:
    return Config(Path(path))


def load_matrix(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """A plain-text matrix (rows of whitespace-separated numbers, ``#`` comments), checked against ``shape``."""
    try:
        m = np.loadtxt(path, comments="#", ndmin=2)
    except (OSError, ValueError) as exc:
        raise ConfError(f"cannot read matrix: {exc}", path=str(path)) from None
    if m.shape != shape:
        raise ConfError(f"matrix is {m.shape[0]}×{m.shape[1]}, expected {shape[0]}×{shape[1]}", path=str(path))
    return m
