"""Frames between the controller, the motor driver and the ESCs (docs/uquad.md §4). Pure: bytes in, frames out.

All frames: sync ``0xA5``, a type letter, a fixed body, CRC-16/IBM-3740 of type + body (little-endian).
Speeds are motor angular speeds in units of 0.1 rad/s (u16).

- ``M`` command, controller → driver: seq u16, 4 × speed u16 (14 bytes). All four zero = stop the motors.
- ``K`` ack, driver → controller: seq u16 (of the command), status u8 (7 bytes): see ``AckStatus``.
- ``E`` ESC set-point, driver → ESCs: 4 × speed u16 (12 bytes), sent continuously.
"""

from __future__ import annotations

import enum
import struct
from binascii import crc_hqx
from typing import NamedTuple

SYNC = 0xA5
SPEED_SCALE = 10.0  # units per rad/s
_BODIES = {ord("M"): struct.Struct("<H4H"), ord("K"): struct.Struct("<HB"), ord("E"): struct.Struct("<4H")}
SIZES = {t: 2 + s.size + 2 for t, s in _BODIES.items()}


class AckStatus(enum.IntEnum):
    OK = 0
    """Applied (sent to the ESCs)."""
    RAMPING = 1
    """Accepted; the motors are still ramping up to the minimum speed, the command applies after the ramp."""
    STOPPED = 2
    """A stop command: the motors are off."""
    OUT_OF_RANGE = 3
    """Refused: a speed outside [min, max] (and not a stop); the previous speeds are kept."""
    ESC_ERROR = 4
    """The driver cannot reach the ESCs: the motors are not being commanded."""


class Frame(NamedTuple):
    kind: str
    fields: tuple[int, ...]


def _crc(data: bytes) -> int:
    return crc_hqx(data, 0xFFFF)


def _build(kind: str, *fields: int) -> bytes:
    body = bytes((ord(kind),)) + _BODIES[ord(kind)].pack(*fields)
    return bytes((SYNC,)) + body + _crc(body).to_bytes(2, "little")


def to_units(speed_rad_s: float) -> int:
    units = round(speed_rad_s * SPEED_SCALE)
    if not 0 <= units <= 0xFFFF:
        raise ValueError(f"motor speed {speed_rad_s} rad/s does not fit the frame (0..{0xFFFF / SPEED_SCALE})")
    return units


def command(seq: int, speeds_rad_s: tuple[float, ...] | list[float]) -> bytes:
    if len(speeds_rad_s) != 4:
        raise ValueError("a motor command carries exactly 4 speeds")
    return _build("M", seq & 0xFFFF, *(to_units(s) for s in speeds_rad_s))


def ack(seq: int, status: AckStatus) -> bytes:
    return _build("K", seq & 0xFFFF, int(status))


def esc(speeds_rad_s: tuple[float, ...] | list[float]) -> bytes:
    return _build("E", *(to_units(s) for s in speeds_rad_s))


def speeds(frame: Frame) -> tuple[float, ...]:
    """The four speeds (rad/s) of an ``M`` or ``E`` frame."""
    values = frame.fields[1:] if frame.kind == "M" else frame.fields
    return tuple(v / SPEED_SCALE for v in values)


class FrameParser:
    """Resynchronising parser: a bad candidate costs one byte; bad frames are counted, partial ones kept back."""

    def __init__(self, accept: str = "MKE") -> None:
        self._accept = {ord(c) for c in accept}
        self._buf = bytearray()
        self.frames = 0
        self.bad_frames = 0
        self._skipping = False

    def _drop(self, n: int) -> None:
        del self._buf[:n]
        if not self._skipping:
            self._skipping = True
            self.bad_frames += 1

    def feed(self, data: bytes) -> list[Frame]:
        buf = self._buf
        buf += data
        out: list[Frame] = []
        while True:
            start = buf.find(SYNC)
            if start < 0:
                if buf:
                    self._drop(len(buf))
                return out
            if start:
                self._drop(start)
            if len(buf) < 2:
                return out
            kind = buf[1]
            if kind not in self._accept:
                self._drop(1)
                continue
            size = SIZES[kind]
            if len(buf) < size:
                return out
            body = bytes(buf[1:size - 2])
            if _crc(body) != int.from_bytes(buf[size - 2:size], "little"):
                self._drop(1)
                continue
            out.append(Frame(chr(kind), _BODIES[kind].unpack(body[1:])))
            del buf[:size]
            self._skipping = False
            self.frames += 1
