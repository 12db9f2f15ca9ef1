"""Encode and decode every DSP message (docs/dsp_protocol.md §4-§5), both directions, in one place.

Each message has a fixed little-endian layout built once as a ``struct.Struct``; telemetry's layout depends on
its mask and is cached per mask. ``encode()`` runs ``protocol.check()`` first, so an out-of-range value is
refused before a byte is produced. Decoding never raises on a *value* (the DSP simulator must be able to
answer OUT_OF_RANGE to a well-formed frame), only on a payload that does not fit its layout.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from enum import IntEnum
from typing import Any

import msgspec

from bbcs.contracts import dsp as p
from modules.dsp.framing import Frame, build_frame


class DspDecodeError(ValueError):
    """A payload that passed the CRC does not fit its message layout (wrong length, reserved bits...)."""


def scale_latlon(deg: float, scale: int = p.LATLON_SCALE) -> int:
    """Degrees → integer units: nearest integer to ``deg × scale``, exact ties away from zero (doc §4.3)."""
    scaled = abs(deg) * scale
    units = math.floor(scaled)
    if scaled - units >= 0.5:
        units += 1
    return -units if deg < 0 else units


def unscale_latlon(units: int, scale: int = p.LATLON_SCALE) -> float:
    return units / scale


_F32 = struct.Struct("<f")


def _f32_inside(value: float, lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> float:
    """``value`` rounded to binary32, nudged toward zero if rounding pushed it past a bound (π, 180...)."""
    f = _F32.unpack(_F32.pack(value))[0]

    def outside(x: float) -> bool:
        return (lo is not None and (x < lo or (lo_open and x == lo))) or (
            hi is not None and (x > hi or (hi_open and x == hi)))

    while outside(f):
        import numpy as np  # rare (a bound crossed by rounding): numpy stays out of the DSP module's start-up

        f = float(np.nextafter(np.float32(f), np.float32(0.0)))
    return f


# Wire kinds: how one struct field becomes one (or more) packed values.
#   f32 / u8 / u16 / u32: plain; bool8: bool as u8; enum8: IntEnum as u8; e4: lat/lon degrees as i32 × 10^4
_FMT = {"f32": "f", "u8": "B", "u16": "H", "u32": "I", "bool8": "B", "enum8": "B", "e4": "i"}


class _Layout:
    """Fixed layout of one message type: the Struct and the field converters in both directions."""

    def __init__(self, cls: type[p.Message], fields: tuple[tuple[str, str], ...]) -> None:
        self.cls = cls
        self.msg_id = int(cls.MSG_ID)
        self.names = tuple(name for name, _ in fields)
        self.struct = struct.Struct("<" + "".join(_FMT[kind] for _, kind in fields))
        self.size = self.struct.size
        types = {f.name: f.type for f in msgspec.inspect.type_info(cls).fields}
        self.to_wire: list[Callable[[Any], Any]] = []
        self.from_wire: list[Callable[[Any], Any]] = []
        for name, kind in fields:
            self.to_wire.append(_to_wire(kind, types[name]))
            self.from_wire.append(_from_wire(kind, types[name]))

    def encode(self, msg: p.Message) -> bytes:
        return self.struct.pack(*[conv(getattr(msg, name))
                                  for name, conv in zip(self.names, self.to_wire, strict=True)])

    def decode(self, payload: bytes) -> p.Message:
        if len(payload) != self.size:
            raise DspDecodeError(f"{self.cls.__name__}: payload of {len(payload)} bytes, "
                                 f"expected {self.size}")
        values = self.struct.unpack(payload)
        pairs = zip(self.names, self.from_wire, values, strict=True)
        return self.cls(**{name: conv(v) for name, conv, v in pairs})


def _to_wire(kind: str, t: Any) -> Callable[[Any], Any]:
    if kind == "f32":
        if isinstance(t, msgspec.inspect.FloatType) and (t.lt is not None or t.gt is not None or (
                t.ge is not None and t.ge > -p.F32_MAX) or (t.le is not None and t.le < p.F32_MAX)):
            lo = t.ge if t.ge is not None else t.gt
            hi = t.le if t.le is not None else t.lt
            return lambda v, lo=lo, hi=hi, lo_open=t.gt is not None, hi_open=t.lt is not None: _f32_inside(
                v, lo, hi, lo_open, hi_open)
        return float
    if kind == "e4":
        return scale_latlon
    return int  # u8/u16/u32, bool8 (True → 1), enum8


def _from_wire(kind: str, t: Any) -> Callable[[Any], Any]:
    if kind == "e4":
        return unscale_latlon
    if kind == "bool8":
        return lambda v: bool(v) if v in (0, 1) else v  # 2..255 stays an int: check() refuses it
    if kind == "enum8":
        enum_cls: type[IntEnum] = t.cls
        return lambda v: enum_cls(v) if v in enum_cls._value2member_map_ else v
    return _identity


def _identity(v: Any) -> Any:
    return v


_F = "f32"
_LAYOUTS: dict[type[p.Message], _Layout] = {
    layout.cls: layout for layout in (
        _Layout(p.SetSpeed, (("speed", _F),)),
        _Layout(p.SetTelemetryMask, (("mask", "u32"),)),
        _Layout(p.SetStateTransmission, (("enable", "bool8"), ("period_ms", "u16"))),
        _Layout(p.ClearError, ()),
        _Layout(p.SetTracking, (("enable", "bool8"),)),
        _Layout(p.InvalidatePath, ()),
        _Layout(p.SetHelicopterType, (("heli_type", "enum8"),)),
        _Layout(p.SetPid, (("axis", "enum8"), ("kp", _F), ("ki", _F), ("kd", _F), ("integral", _F),
                           ("awu_max", _F), ("awu_min", _F), ("reference", _F), ("offset", _F),
                           ("sat_high", _F), ("sat_low", _F))),
        _Layout(p.SetMode, (("mode", "enum8"),)),
        _Layout(p.SetHeading, (("heading_deg", _F),)),
        _Layout(p.AddWaypoint, (("lat", "e4"), ("lon", "e4"), ("alt", _F))),
        _Layout(p.SetRefs, (("ref_altura", _F), ("error_longitudinal", _F), ("error_lateral", _F),
                            ("ref_heading", _F), ("ref_rpm_motor", _F))),
        _Layout(p.SetPanTiltMode, (("mode", "enum8"),)),
        _Layout(p.SetPanTiltAngles, (("pan_deg", _F), ("tilt_deg", _F))),
        _Layout(p.SetPanTiltTarget, (("lat", "e4"), ("lon", "e4"), ("alt", _F))),
        _Layout(p.Abort, ()),
        _Layout(p.Ping, ()),
        _Layout(p.Ack, (("acked_id", "u8"), ("acked_seq", "u8"), ("status", "u16"))),
        _Layout(p.DspError, (("time_ms", "u32"), ("code", "u16"), ("related_id", "u8"))),
    )
}
_BY_ID: dict[int, _Layout] = {layout.msg_id: layout for layout in _LAYOUTS.values()}


# --- telemetry ---------------------------------------------------------------------------------------------

_TELEMETRY_HEAD = struct.Struct("<II")
_E7 = p.TELEMETRY_LATLON_SCALE
_E4 = p.LATLON_SCALE


def _pos_out(v: p.TelPosition) -> tuple:
    return scale_latlon(v.lat, _E7), scale_latlon(v.lon, _E7), v.alt


def _nav_out(v: p.NavTarget) -> tuple:
    return scale_latlon(v.lat, _E4), scale_latlon(v.lon, _E4), v.alt, v.distance


def _status_out(v: p.DspStatus) -> tuple:
    flags = (1 if v.tracking else 0) | (2 if v.path_valid else 0) | (4 if v.airborne else 0) | v.reserved_flags
    return int(v.mode), flags, v.queue_length


def _status_in(mode: int, flags: int, queue: int) -> p.DspStatus:
    """As received: a mode, queue length or reserved bit outside the declared ranges is refused by ``check()``
    with the others (one rule for every field, bbcs/contracts/dsp.py), not here."""
    return p.DspStatus(mode=mode, tracking=bool(flags & 1), path_valid=bool(flags & 2),
                       airborne=bool(flags & 4), queue_length=queue, reserved_flags=flags & 0xF8)


def _heading_out(deg: float) -> float:
    """Heading and yaw are [-180, 180): a double just below 180 must not round up to 180.0 in binary32. A value
    already outside goes out as it is (the simulator's fault injection frames one on purpose)."""
    return _f32_inside(deg, -180.0, 180.0, False, True) if -180.0 <= deg < 180.0 else deg


# (attribute, struct format, values-out, object-in); in mask bit order
_TELEMETRY_FIELDS: tuple[tuple[str, str, Callable[[Any], tuple], Callable[..., Any]], ...] = (
    ("position", "iif", _pos_out,
     lambda la, lo, al: p.TelPosition(lat=la / _E7, lon=lo / _E7, alt=al)),
    ("attitude", "fff", lambda v: (v.roll, v.pitch, _heading_out(v.yaw)),
     lambda r, pi, y: p.TelAttitude(roll=r, pitch=pi, yaw=y)),
    ("velocity", "fff", lambda v: (v.vn, v.ve, v.vd), lambda a, b, c: p.TelVelocity(vn=a, ve=b, vd=c)),
    ("angular_rate", "fff", lambda v: (v.p, v.q, v.r), lambda a, b, c: p.AngularRate(p=a, q=b, r=c)),
    ("heading", "f", lambda v: (_heading_out(v),), lambda h: h),
    ("status", "BBH", _status_out, _status_in),
    ("nav", "iiff", _nav_out,
     lambda la, lo, al, d: p.NavTarget(lat=la / _E4, lon=lo / _E4, alt=al, distance=d)),
    ("speed", "ff", lambda v: (v.commanded, v.ground), lambda c, g: p.SpeedInfo(commanded=c, ground=g)),
    ("pan_tilt", "Bff", lambda v: (int(v.mode), v.pan, v.tilt),
     lambda m, pan, tilt: p.PanTiltState(mode=m, pan=pan, tilt=tilt)),
    ("error_code", "H", lambda v: (v,), lambda c: c),
    ("engine", "ff", lambda v: (v.rotor_rpm, v.battery_v), lambda r, b: p.Engine(rotor_rpm=r, battery_v=b)),
)
assert tuple(f[0] for f in _TELEMETRY_FIELDS) == p.TELEMETRY_ATTRS
_FIELD_SIZES = tuple(struct.calcsize("<" + f[1]) for f in _TELEMETRY_FIELDS)


class _MaskLayout:
    __slots__ = ("struct", "fields", "counts")

    def __init__(self, mask: int) -> None:
        chosen = [f for bit, f in enumerate(_TELEMETRY_FIELDS) if mask >> bit & 1]
        self.fields = chosen
        self.counts = [len(f[1]) for f in chosen]
        self.struct = struct.Struct("<II" + "".join(f[1] for f in chosen))


_MASK_LAYOUTS: dict[int, _MaskLayout] = {}


def _mask_layout(mask: int) -> _MaskLayout:
    layout = _MASK_LAYOUTS.get(mask)
    if layout is None:
        layout = _MASK_LAYOUTS[mask] = _MaskLayout(mask)
    return layout


def telemetry_size(mask: int) -> int:
    """Payload bytes of a telemetry frame carrying ``mask``."""
    return _TELEMETRY_HEAD.size + sum(s for bit, s in enumerate(_FIELD_SIZES) if mask >> bit & 1)


def _encode_telemetry(msg: p.Telemetry) -> bytes:
    mask = msg.mask
    layout = _mask_layout(mask)
    values: list[Any] = [msg.time_ms, mask]
    for attr, _, out, _ in layout.fields:
        values.extend(out(getattr(msg, attr)))
    return layout.struct.pack(*values)


def _decode_telemetry(payload: bytes) -> p.Telemetry:
    if len(payload) < 8:
        raise DspDecodeError(f"telemetry payload of {len(payload)} bytes is shorter than its 8-byte head")
    time_ms, mask = _TELEMETRY_HEAD.unpack_from(payload)
    if mask & ~p.TELEMETRY_ALL:
        raise DspDecodeError(f"telemetry mask {mask:#x} has reserved bits set")
    layout = _mask_layout(mask)
    if layout.struct.size != len(payload):
        raise DspDecodeError(f"telemetry mask {mask:#x} needs {layout.struct.size} bytes, got {len(payload)}")
    values = layout.struct.unpack(payload)
    kwargs: dict[str, Any] = {}
    i = 2
    for (attr, _, _, make), count in zip(layout.fields, layout.counts, strict=True):
        kwargs[attr] = make(*values[i:i + count])
        i += count
    return p.Telemetry(time_ms=time_ms, **kwargs)


def _telemetry_lengths() -> frozenset[int]:
    sums = {0}
    for size in _FIELD_SIZES:
        sums |= {s + size for s in sums}
    return frozenset(_TELEMETRY_HEAD.size + s for s in sums)


# --- public API --------------------------------------------------------------------------------------------

PC_TO_DSP_LENGTHS: dict[int, frozenset[int]] = {
    int(cls.MSG_ID): frozenset({_LAYOUTS[cls].size}) for cls in p.COMMANDS}
DSP_TO_PC_LENGTHS: dict[int, frozenset[int]] = {
    int(p.MsgId.ACK): frozenset({_LAYOUTS[p.Ack].size}),
    int(p.MsgId.ERROR): frozenset({_LAYOUTS[p.DspError].size}),
    int(p.MsgId.TELEMETRY): _telemetry_lengths(),
}


def encode_payload(msg: p.Message) -> bytes:
    """Validate ``msg`` (DspValueError if a field is out of range) and pack its payload."""
    p.check(msg)
    if isinstance(msg, p.Telemetry):
        return _encode_telemetry(msg)
    return _LAYOUTS[type(msg)].encode(msg)


def encode(msg: p.Message, seq: int) -> bytes:
    """A complete frame for ``msg`` with sequence number ``seq``."""
    return build_frame(int(msg.MSG_ID), seq & 0xFF, encode_payload(msg))


def decode_payload(msg_id: int, payload: bytes) -> p.Message:
    """The message in a payload; DspDecodeError for an unknown id or a payload that does not fit."""
    if msg_id == p.MsgId.TELEMETRY:
        return _decode_telemetry(payload)
    layout = _BY_ID.get(msg_id)
    if layout is None:
        raise DspDecodeError(f"unknown message id {msg_id:#04x}")
    return layout.decode(payload)


def decode(frame: Frame) -> p.Message:
    return decode_payload(frame.msg_id, frame.payload)


def message_name(msg_id: int) -> str:
    try:
        return p.MsgId(msg_id).name
    except ValueError:
        return f"ID_{msg_id:#04x}"
