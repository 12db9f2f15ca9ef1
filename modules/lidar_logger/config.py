"""Logger configuration: the ``LIDAR: logger { ... }`` group of a robot .conf, merged with command-line
options or module params into LoggerSettings.

Example group (robot .conf, SPEC §4 format)::

    LIDAR: logger {
        VEHICLE: CB5000         # or PILATUS_PORTER: the GPS lever arm (LEVER_ARM: [x, y, z] overrides)
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

from bbcs import ConfDocument, ConfError, load_conf, load_params, raise_first, struct_param_errors
from modules.lidar_logger.georef import Mounting
from modules.lidar_logger.logger import LoggerSettings
from modules.lidar_logger.vehicles import VEHICLES, vehicle_key

CONF_GROUP = ("LIDAR", "logger")


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


    def to_settings(self, *, progress: bool = True) -> LoggerSettings:
        """Logger settings from these values; a missing device address is a ValueError."""
        if not self.mtig_port or not self.ldmrs_host:
            raise ValueError("need the MTi-G port and the LD-MRS host (--mtig-port/--ldmrs-host, "
                             "MTIG_PORT/LDMRS_HOST in the .conf, or module params)")
        return LoggerSettings(
            mtig_port=self.mtig_port, mtig_baud=self.mtig_baud, ldmrs_host=self.ldmrs_host,
            ldmrs_port=self.ldmrs_port, out_dir=Path(self.out_dir),
            duration_s=self.duration_min * 60.0 if self.duration_min > 0 else None,
            event_timeout_s=self.event_timeout_s, binary=self.binary_log, vehicle=vehicle_key(self.vehicle),
            lever_arm=self.lever_arm_m, mounting=self.mounting_struct,
            sync_scanner_clock=self.sync_scanner_clock, progress=progress)


LIST_PARAMS = ("mounting", "lever_arm")
"""Params given as comma-separated numbers (``mounting=0,90,0,0.1,0,-0.15``)."""


class LidarParams(msgspec.Struct, frozen=True, kw_only=True):
    """The lidar logger's manifest ``params``: the ``LIDAR: logger`` group's keys in lower case, each optional
    (the .conf's value, if any, stays), with the group's types and ranges. ``cromat launch --check``
    (:func:`lidar_param_errors`) and the module (:func:`load_lidar_params`) read them through the same function."""

    vehicle: str | None = None
    mtig_port: str | None = None
    mtig_baud: Annotated[int, msgspec.Meta(gt=0)] | None = None
    ldmrs_host: str | None = None
    ldmrs_port: Annotated[int, msgspec.Meta(ge=1, le=65535)] | None = None
    duration_min: Annotated[float, msgspec.Meta(ge=0)] | None = None
    event_timeout_s: Annotated[float, msgspec.Meta(gt=0)] | None = None
    out_dir: str | None = None
    binary_log: bool | None = None
    sync_scanner_clock: bool | None = None
    mounting: tuple[float, float, float, float, float, float] | None = None
    lever_arm: tuple[float, float, float] | None = None


def _split_lists(params: dict[str, str]) -> dict[str, object]:
    return {key: (value.split(",") if key in LIST_PARAMS else value) for key, value in params.items()}


def lidar_param_errors(params: dict[str, str]) -> list[tuple[str, str]]:
    """Every problem of the manifest's lidar logger ``params``, (key, reason); an unknown vehicle is one."""
    errors = struct_param_errors(LidarParams, _split_lists(params), what="lidar_logger")  # type: ignore[arg-type]
    vehicle = params.get("vehicle")
    if vehicle is not None:
        try:
            vehicle_key(vehicle)
        except ValueError as exc:
            errors.append(("vehicle", f"bad value {vehicle!r}: {exc}"))
    return errors


def load_lidar_params(params: dict[str, str]) -> dict[str, object]:
    """The params given, as typed overrides for :func:`merge_lidar_conf`; a ``ParamError`` (exit 78) naming
    every problem :func:`lidar_param_errors` finds."""
    raise_first(lidar_param_errors(params), source="manifest params of lidar_logger")
    loaded = load_params(LidarParams, _split_lists(params), what="lidar_logger")  # type: ignore[arg-type]
    return {key: value for key, value in msgspec.structs.asdict(loaded).items() if value is not None}


def conf_errors(doc: ConfDocument) -> list[ConfError]:
    """Every mistake in the ``LIDAR: logger`` group of a parsed .conf, each with file:line, for ``cromat conf
    check`` and ``cromat launch --check`` (``LidarLoggerModule.conf_errors``); a .conf without the group has none
    (the module then takes everything from its params)."""
    group = next((g for g in doc.groups_of(CONF_GROUP[0]) if g.name == CONF_GROUP[1]), None)
    if group is None:
        return []
    errors = group.errors_for(LidarConf)
    vehicle = group.entries.get("VEHICLE")
    if vehicle is not None and isinstance(vehicle.value, str):
        try:
            vehicle_key(vehicle.value)
        except ValueError as exc:
            errors.append(ConfError(str(exc), path=doc.path, line=vehicle.line, column=vehicle.column))
    return sorted(errors, key=lambda e: (e.line or 0, e.column or 0))


def load_lidar_conf(path: str | os.PathLike[str], *, required: bool = True) -> LidarConf | None:
    """Read the ``LIDAR: logger`` group; any problem is a ConfError with file and line (the first of
    :func:`conf_errors`). Without the group: a ConfError, or None when not ``required``."""
    doc = load_conf(path)
    groups = [g for g in doc.groups_of(CONF_GROUP[0]) if g.name == CONF_GROUP[1]]
    if not groups:
        if required:
            raise ConfError(f"missing group '{CONF_GROUP[0]}: {CONF_GROUP[1]}'", path=str(path))
        return None
    errors = conf_errors(doc)
    if errors:
        raise errors[0]
    return groups[0].to_struct(LidarConf)


def merge_lidar_conf(base: LidarConf | None, overrides: dict[str, object]) -> LidarConf:
    """``base`` (from a .conf, or nothing) with ``overrides`` on top (field names; None = not given)."""
    values = {} if base is None else msgspec.structs.asdict(base)
    unknown = set(overrides) - set(LidarConf.__struct_fields__)
    if unknown:
        raise ValueError(f"unknown lidar setting(s): {', '.join(sorted(unknown))}")
    values.update({k: v for k, v in overrides.items() if v is not None})
    if values.get("vehicle") is None:
        raise ValueError("say which vehicle (--vehicle, VEHICLE in the .conf, or the vehicle param): "
                         "it chooses the GPS lever arm")
    vehicle_key(str(values["vehicle"]))
    try:
        return msgspec.convert({k.upper(): v for k, v in values.items()}, LidarConf, strict=False)
    except msgspec.ValidationError as exc:
        raise ValueError(f"lidar settings: {exc}") from None


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
