"""Logger configuration: the vehicle table (seed Table 12) and the ``LIDAR: logger { ... }`` group of a
robot .conf.

Example group (robot .conf, SPEC §4 format)::

    LIDAR: logger {
        VEHICLE: CB5000                 # or PILATUS_PORTER: chooses the MTi-G GPS lever arm
        MTIG_PORT: /dev/ttyUSB1
        LDMRS_HOST: 192.168.0.1
        LDMRS_PORT: 12002
        DURATION_MIN: 20                # 0 = until Ctrl+C or a silent scanner
        EVENT_TIMEOUT_S: 15
        OUT_DIR: /media/sd/lidar
        BINARY_LOG: true
        MOUNTING: [0, 90, 0, 0.10, 0, -0.15]   # scanner in the body frame: roll pitch yaw deg, x y z m
    }
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import msgspec

from bbcs.conf import ConfError, load_conf
from modules.lidar_logger.georef import Mounting

VEHICLES: dict[str, tuple[float, float, float]] = {
    "PILATUS_PORTER": (-0.45, -0.04, 0.0),
    "CB5000": (-0.34, 0.01, 0.26),
}
"""GPS antenna relative to the MTi-G in its body frame, metres (seed Table 12)."""

CONF_GROUP = ("LIDAR", "logger")


def vehicle_key(name: str) -> str:
    key = name.strip().upper().replace("-", "_").replace(" ", "_")
    if key not in VEHICLES:
        raise ValueError(f"unknown vehicle {name!r}; known: {', '.join(sorted(VEHICLES))}")
    return key


class LidarConf(msgspec.Struct, frozen=True, kw_only=True, rename="upper", forbid_unknown_fields=True):
    """The keys of the ``LIDAR: logger`` group (a config file, not a bus message: unknown keys are errors)."""

    vehicle: str
    mtig_port: str | None = None
    mtig_baud: Annotated[int, msgspec.Meta(gt=0)] = 115200
    ldmrs_host: str | None = None
    ldmrs_port: Annotated[int, msgspec.Meta(ge=1, le=65535)] = 12002
    duration_min: Annotated[float, msgspec.Meta(ge=0)] = 0.0
    event_timeout_s: Annotated[float, msgspec.Meta(gt=0)] = 15.0
    out_dir: str = "."
    binary_log: bool = False
    sync_scanner_clock: bool = False
    mounting: tuple[float, float, float, float, float, float] = (0.0, 90.0, 0.0, 0.0, 0.0, 0.0)
    lever_arm: tuple[float, float, float] | None = None

    @property
    def mounting_struct(self) -> Mounting:
        return Mounting(*self.mounting)

    @property
    def lever_arm_m(self) -> tuple[float, float, float]:
        return self.lever_arm if self.lever_arm is not None else VEHICLES[vehicle_key(self.vehicle)]


def load_lidar_conf(path: str | os.PathLike[str]) -> LidarConf:
    """Read the ``LIDAR: logger`` group; any problem is a ConfError with file and line."""
    doc = load_conf(path)
    group = doc.group(*CONF_GROUP)
    conf = group.to_struct(LidarConf)
    try:
        vehicle_key(conf.vehicle)
    except ValueError as exc:
        entry = group.entries["VEHICLE"]
        raise ConfError(str(exc), path=str(path), line=entry.line, column=entry.column) from None
    return conf


def read_config_file(path: str | os.PathLike[str]) -> dict[str, str]:
    """Read a run's ``ConfigFile_<date>`` (flat ``key: value`` lines, ``#`` comments)."""
    out: dict[str, str] = {}
    for line in Path(path).read_text(encoding="ascii").splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            key, sep, value = line.partition(":")
            if sep:
                out[key.strip()] = value.strip()
    return out
