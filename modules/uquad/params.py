"""The uQuad modules' manifest ``params``: one struct per module, checked by ``cromat launch --check`` (the classes'
``param_errors``) and loaded by the modules through the same function (``bbcs.params``), so the two never
disagree. A bad param is a ``ParamError`` (exit 78, not restarted)."""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from bbcs import load_params, raise_first, struct_param_errors


class UquadParams(msgspec.Struct, frozen=True, kw_only=True):
    """The flight module (``modules.uquad``)."""

    imu: str = ""
    """IMU serial device or ``tcp://HOST:PORT`` (the simulator); empty: the .conf's ``IMU_PORT``."""
    gps: str = ""
    """GPS serial device or ``tcp://HOST:PORT``; empty: the .conf's ``GPS_PORT``."""
    motor: str = "sim"
    """Motor link (``sim``, a device or ``tcp://HOST:PORT``)."""
    clock: Literal["wall", "imu"] = "wall"
    """What times the flight loop: the host's clock or the IMU's sample stamps."""
    record_raw: str = ""
    """File to record the raw IMU stream to (empty: none)."""
    nice: Annotated[int, msgspec.Meta(ge=-20, le=19)] = 0
    controller: Literal["hover", "setpoint"] = "hover"


class LoggerParams(msgspec.Struct, frozen=True, kw_only=True):
    """A logging process (``modules.uquad.logger``)."""

    kind: Literal["", "imu_raw", "state", "control"] = ""
    """The data type; must match the manifest's ``class`` when given."""
    dir: str = ""
    """Folder of the log files; empty: the .conf's ``LOG_DIR``."""


def uquad_param_errors(params: dict[str, str]) -> list[tuple[str, str]]:
    """Every problem of the flight module's manifest ``params``, (key, reason)."""
    return struct_param_errors(UquadParams, params, what="uquad")


def load_uquad_params(params: dict[str, str]) -> UquadParams:
    return load_params(UquadParams, params, what="uquad")


def logger_param_errors(params: dict[str, str], data_type: str) -> list[tuple[str, str]]:
    """Every problem of a logger's manifest ``params``; a ``kind`` other than the class's data type is one."""
    errors = struct_param_errors(LoggerParams, params, what="logger")
    kind = params.get("kind", "")
    if not any(key == "kind" for key, _ in errors) and kind not in ("", data_type):
        errors.append(("kind", f"bad value {kind!r}: this logger class logs {data_type!r}"))
    return errors


def load_logger_params(params: dict[str, str], data_type: str) -> LoggerParams:
    raise_first(logger_param_errors(params, data_type), source="manifest params of the logger")
    return load_params(LoggerParams, params, what="logger")
