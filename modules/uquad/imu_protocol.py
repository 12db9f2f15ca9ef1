"""The uQuad IMU's serial frames (seed 002 §1.3) and a resynchronising parser. Pure: bytes in, frames out.

A frame every 10 ms: ``A``, loop time (µs), accelerometer xyz, gyro xyz, magnetometer xyz (ADC counts, the
average of two samples), temperature (°C × 10), pressure (Pa), ``Z``.

- ASCII: the fields as decimal integers separated by ``\\t``, the line ended by ``\\n`` (or ``\\r\\n``, as
  Arduino's ``println`` ends it).
- Binary: the same fields with no separators, little-endian, fixed widths (docs/uquad.md §2):
  ``A`` (1) · loop_us u16 · 9 × i16 · temp i16 · pressure u32 · ``Z`` (1) = 28 bytes.

The parser never passes a partial frame on: a candidate is delivered only when it is complete, well-formed and
its values are physically possible; otherwise its first byte is dropped, the search restarts at the next byte
(so a real frame starting inside a false one is still found) and the bad frame is counted.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import NamedTuple

START = ord("A")
END = ord("Z")
BINARY = struct.Struct("<cH9hhIc")
BINARY_SIZE = BINARY.size  # 28
MAX_ASCII_LINE = 128
"""Longest valid ASCII frame is ~90 characters: a longer run without ``\\n`` is garbage."""
TEMP_RANGE = (-400, 850)  # °C × 10: the barometer's operating range
PRESSURE_RANGE = (30_000, 110_000)  # Pa


class ImuFrame(NamedTuple):
    """One raw IMU frame, as the board sent it."""

    loop_us: int
    acc: tuple[int, int, int]
    gyro: tuple[int, int, int]
    mag: tuple[int, int, int]
    temp_x10: int
    pressure_pa: int


def plausible(frame: ImuFrame) -> bool:
    """Values a working board can send (a false sync in binary mode usually fails this)."""
    return (TEMP_RANGE[0] <= frame.temp_x10 <= TEMP_RANGE[1]
            and PRESSURE_RANGE[0] <= frame.pressure_pa <= PRESSURE_RANGE[1]
            and 0 <= frame.loop_us <= 0xFFFF
            and all(-32768 <= v <= 32767 for v in (*frame.acc, *frame.gyro, *frame.mag)))


def encode_ascii(frame: ImuFrame) -> bytes:
    fields = ("A", frame.loop_us, *frame.acc, *frame.gyro, *frame.mag, frame.temp_x10, frame.pressure_pa, "Z")
    return ("\t".join(str(f) for f in fields) + "\n").encode("ascii")


def encode_binary(frame: ImuFrame) -> bytes:
    if not plausible(frame):
        raise ValueError(f"frame does not fit the binary field widths or ranges: {frame}")
    return BINARY.pack(b"A", frame.loop_us, *frame.acc, *frame.gyro, *frame.mag, frame.temp_x10,
                       frame.pressure_pa, b"Z")


def decode_ascii_line(line: bytes) -> ImuFrame | None:
    """One line without its ``\\n``; None when it is not exactly a valid frame."""
    parts = line.split(b"\t")
    if len(parts) != 14 or parts[0] != b"A" or parts[-1] != b"Z":
        return None
    try:
        v = [int(p) for p in parts[1:-1]]
    except ValueError:
        return None
    frame = ImuFrame(v[0], (v[1], v[2], v[3]), (v[4], v[5], v[6]), (v[7], v[8], v[9]), v[10], v[11])
    return frame if plausible(frame) else None


def decode_binary(data: bytes | bytearray | memoryview) -> ImuFrame | None:
    """Exactly BINARY_SIZE bytes; None when they are not a valid frame."""
    if len(data) != BINARY_SIZE:
        return None
    a, loop_us, ax, ay, az, gx, gy, gz, mx, my, mz, temp, pres, z = BINARY.unpack(data)
    if a != b"A" or z != b"Z":
        return None
    frame = ImuFrame(loop_us, (ax, ay, az), (gx, gy, gz), (mx, my, mz), temp, pres)
    return frame if plausible(frame) else None


@dataclass
class ParserStats:
    frames: int = 0
    bad_frames: int = 0
    """Candidates rejected (wrong shape, bad number, impossible value) plus runs of garbage skipped."""
    bytes_in: int = 0
    bytes_discarded: int = 0


class ImuParser:
    """Feed bytes as they arrive; get back the complete frames they finish. ``mode`` is ``ascii`` or ``binary``."""

    def __init__(self, mode: str = "binary") -> None:
        if mode not in ("ascii", "binary"):
            raise ValueError(f"IMU mode must be 'ascii' or 'binary', not {mode!r}")
        self.mode = mode
        self.stats = ParserStats()
        self._buf = bytearray()
        self._skipping = False

    def feed(self, data: bytes) -> list[ImuFrame]:
        self.stats.bytes_in += len(data)
        self._buf += data
        return self._ascii() if self.mode == "ascii" else self._binary()

    def _drop(self, n: int) -> None:
        """Discard ``n`` bytes; a run of discards counts as one bad frame."""
        del self._buf[:n]
        self.stats.bytes_discarded += n
        if not self._skipping:
            self._skipping = True
            self.stats.bad_frames += 1

    def _deliver(self, frame: ImuFrame, n: int, out: list[ImuFrame]) -> None:
        del self._buf[:n]
        self._skipping = False
        self.stats.frames += 1
        out.append(frame)

    def _binary(self) -> list[ImuFrame]:
        out: list[ImuFrame] = []
        buf = self._buf
        while True:
            start = buf.find(b"A")
            if start < 0:
                if buf:
                    self._drop(len(buf))
                return out
            if start:
                self._drop(start)
            if len(buf) < BINARY_SIZE:
                return out  # wait for the rest: never a partial frame
            frame = decode_binary(memoryview(buf)[:BINARY_SIZE])
            if frame is None:
                self._drop(1)
            else:
                self._deliver(frame, BINARY_SIZE, out)

    def _ascii(self) -> list[ImuFrame]:
        out: list[ImuFrame] = []
        buf = self._buf
        while True:
            end = buf.find(b"\n")
            if end < 0:
                if len(buf) > MAX_ASCII_LINE:
                    self._drop(ascii_garbage(buf))
                return out
            line = bytes(buf[:end])
            if line.endswith(b"\r"):  # CR LF (Arduino println) ends a line as LF does
                line = line[:-1]
            # a frame may start mid-line after garbage: take the last "A\t" in the line
            start = line.rfind(b"A\t")
            frame = decode_ascii_line(line[start:]) if start >= 0 else None
            if frame is None:
                self._drop(end + 1)
                continue
            if start > 0:
                self._drop(start)
            self._deliver(frame, end + 1 - start, out)


def ascii_garbage(buf: bytes | bytearray) -> int:
    """How many leading bytes of a run longer than MAX_ASCII_LINE without ``\\n`` cannot belong to a frame: all
    but the last ``A\\t`` (or a final ``A``) within the newest MAX_ASCII_LINE bytes, where a frame may have begun
    (dropping the whole run lost a frame whose first bytes it held when bytes arrive in small reads)."""
    floor = max(0, len(buf) - MAX_ASCII_LINE)
    start = buf.rfind(b"A\t", floor)
    if start >= 0:
        return start
    return len(buf) - 1 if buf.endswith(b"A") else len(buf)
