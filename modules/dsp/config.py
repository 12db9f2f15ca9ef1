"""The DSP part of a robot .conf (SPEC §4) as one typed, range-checked DspConfig.

Keys (top level): ``DSP_PORT``, ``DSP_BAUD``, ``HELICOPTER_TYPE``, ``TELEMETRY`` (list of telemetry field
names), ``TELEMETRY_PERIOD_MS``, ``MAX_SPEED``, ``DSP_ACK_TIMEOUT``, ``DSP_RETRIES``; groups ``PID: <AXIS>``
with the seed's ten keys. Every mistake is a ConfError with the file and line of the key or group at fault.
"""

from __future__ import annotations

import os
from typing import Annotated

import msgspec
from msgspec import Meta

from bbcs import ConfDocument, ConfError, ConfGroup, load_conf
from bbcs.contracts.dsp import (
    F32,
    MAX_SPEED_LIMIT,
    Axis,
    DspValueError,
    HeliType,
    SetPid,
    check,
    parse_telemetry_fields,
)


class _DspKeys(msgspec.Struct, kw_only=True, rename={
        "port": "DSP_PORT", "baudrate": "DSP_BAUD", "heli_type": "HELICOPTER_TYPE", "telemetry": "TELEMETRY",
        "telemetry_period_ms": "TELEMETRY_PERIOD_MS", "max_speed": "MAX_SPEED",
        "ack_timeout_s": "DSP_ACK_TIMEOUT", "retries": "DSP_RETRIES"}):
    port: str
    baudrate: Annotated[int, Meta(ge=50, le=12_000_000)] = 921_600
    heli_type: str
    telemetry: list[str]
    telemetry_period_ms: Annotated[int, Meta(ge=10, le=60_000)] = 50
    max_speed: Annotated[float, Meta(gt=0.0, le=MAX_SPEED_LIMIT)]
    ack_timeout_s: Annotated[float, Meta(gt=0.0, le=10.0)] = 0.25
    retries: Annotated[int, Meta(ge=0, le=20)] = 3


class _PidKeys(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """The seed's PID group (004 §5.3.1.1), key for key."""

    Kp: F32
    Ki: F32
    Kd: F32
    valor_int: F32
    max_awu: F32
    min_awu: F32
    referencia: F32
    offset: F32
    sat_encima: F32
    sat_deb: F32


class DspConfig(msgspec.Struct, frozen=True, kw_only=True):
    """Everything the DSP link and its start-up sequence need from the robot .conf."""

    port: str
    baudrate: int = 921_600
    heli_type: HeliType
    telemetry_mask: int
    telemetry_period_ms: int = 50
    max_speed: float
    ack_timeout_s: float = 0.25
    retries: int = 3
    pid_groups: tuple[SetPid, ...] = ()
    source: str = "<string>"


def _error_at(doc: ConfDocument, key: str, message: str) -> ConfError:
    entry = doc.entries.get(key)
    return ConfError(message, path=doc.path, line=None if entry is None else entry.line,
                     column=None if entry is None else entry.column)


def _heli_type(doc: ConfDocument, text: str) -> HeliType:
    word = text.strip().upper()
    if word.isdigit() and int(word) in HeliType._value2member_map_:
        return HeliType(int(word))
    if word in HeliType.__members__:
        return HeliType[word]
    names = ", ".join(f"{t.name} ({t.value})" for t in HeliType)
    raise _error_at(doc, "HELICOPTER_TYPE", f"key 'HELICOPTER_TYPE': unknown helicopter type {text!r}; "
                                            f"use one of {names}")


def _axis(group: ConfGroup) -> Axis:
    name = group.name.strip().upper()
    if name not in Axis.__members__:
        axes = ", ".join(a.name for a in Axis)
        raise ConfError(f"group '{group.label}': unknown controlled axis {group.name!r}; use one of {axes}",
                        path=group.path, line=group.line, column=group.column)
    return Axis[name]


def _pid(group: ConfGroup) -> SetPid:
    axis = _axis(group)
    keys = group.to_struct(_PidKeys)
    pid = SetPid(axis=axis, kp=keys.Kp, ki=keys.Ki, kd=keys.Kd, integral=keys.valor_int,
                 awu_max=keys.max_awu, awu_min=keys.min_awu, reference=keys.referencia, offset=keys.offset,
                 sat_high=keys.sat_encima, sat_low=keys.sat_deb)
    try:
        check(pid)
    except DspValueError as exc:
        raise ConfError(f"group '{group.label}': {exc}", path=group.path, line=group.line,
                        column=group.column) from None
    return pid


def _pid_errors(group: ConfGroup) -> list[ConfError]:
    """The axis, every key, then (only when those are fine) the ranges ``check`` applies to the SetPid."""
    errors = group.errors_for(_PidKeys)
    if errors or group.name.strip().upper() not in Axis.__members__:
        try:
            _axis(group)
        except ConfError as exc:
            errors.insert(0, exc)
        return errors
    try:
        _pid(group)
    except ConfError as exc:
        errors.append(exc)
    return errors


def conf_errors(doc: ConfDocument) -> list[ConfError]:
    """Every mistake in the DSP part of a parsed .conf (all of them, each with file:line), for
    ``cromat conf check`` and ``cromat launch --check``; empty when :func:`dsp_config_from` would succeed."""
    errors = doc.errors_for(_DspKeys)
    bad = {e.line for e in errors}
    telemetry = doc.entries.get("TELEMETRY")
    if telemetry is not None and telemetry.line not in bad:
        names = telemetry.value if isinstance(telemetry.value, list) else [telemetry.value]
        for i, name in enumerate(names):
            try:
                parse_telemetry_fields([name])
            except ValueError as exc:
                errors.append(_error_at(doc, "TELEMETRY", f"key 'TELEMETRY' (item {i + 1} of the list): {exc}"))
    heli = doc.entries.get("HELICOPTER_TYPE")
    if heli is not None and isinstance(heli.value, str):
        try:
            _heli_type(doc, heli.value)
        except ConfError as exc:
            errors.append(exc)
    for group in doc.groups_of("PID"):
        errors += _pid_errors(group)
    return sorted(errors, key=lambda e: (e.line or 0, e.column or 0))


def dsp_config_from(doc: ConfDocument) -> DspConfig:
    """Build the DspConfig of a parsed .conf; ConfError (file:line) on any missing or bad value (the first of
    :func:`conf_errors`, so the module and ``cromat conf check`` never disagree)."""
    errors = conf_errors(doc)
    if errors:
        raise errors[0]
    keys = doc.to_struct(_DspKeys)
    try:
        mask = parse_telemetry_fields(keys.telemetry)
    except ValueError as exc:
        raise _error_at(doc, "TELEMETRY", f"key 'TELEMETRY': {exc}") from None
    return DspConfig(port=keys.port, baudrate=keys.baudrate, heli_type=_heli_type(doc, keys.heli_type),
                     telemetry_mask=mask, telemetry_period_ms=keys.telemetry_period_ms,
                     max_speed=keys.max_speed,
                     ack_timeout_s=keys.ack_timeout_s, retries=keys.retries,
                     pid_groups=tuple(_pid(g) for g in doc.groups_of("PID")), source=doc.path)


def load_dsp_config(path: str | os.PathLike[str], *, port: str | None = None) -> DspConfig:
    """Read a robot .conf; ``port`` overrides DSP_PORT (the manager points it at a simulator's pty)."""
    cfg = dsp_config_from(load_conf(path))
    return cfg if port is None else msgspec.structs.replace(cfg, port=port)
