"""GPS over NMEA 0183 (GGA position + RMC velocity), and the seed's fake modes. Pure apart from ``FakeGps``'s RNG.

The reader accepts ``$..GGA`` and ``$..RMC`` sentences with a valid checksum; anything else on the line is
dropped and counted. A fix is complete when an RMC (status A: velocity) follows a GGA (quality ≥ 1: position)
of the same UTC time, the order receivers send them in.
Fake modes (seed 002 §1.2.1): ``zeros`` (position and velocity all zero) or ``random`` (uniform in ±range m,
±range/10 m/s), at 1 Hz, in the local frame; ``none`` disables the GPS (the estimator runs without it).
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass
from functools import reduce

KNOT_M_S = 0.514444
MAX_LINE = 120


@dataclass(frozen=True)
class GpsFix:
    """A GPS sample: WGS84 degrees, metres above sea level, ground velocity east/north (m/s)."""

    lat: float
    lon: float
    alt: float
    ve: float
    vn: float
    satellites: int
    quality: int


def checksum(body: str) -> str:
    return f"{reduce(lambda a, c: a ^ ord(c), body, 0):02X}"


def _sentence(body: str) -> bytes:
    return f"${body}*{checksum(body)}\r\n".encode("ascii")


def _dm(value: float, deg_digits: int) -> tuple[str, int]:
    sign = 1 if value >= 0 else -1
    value = abs(value)
    deg = int(value)
    minutes = (value - deg) * 60
    return f"{deg:0{deg_digits}d}{minutes:07.4f}", sign


def encode(fix: GpsFix, utc_s: float) -> bytes:
    """The GGA + RMC pair a receiver sends for one fix."""
    t = utc_s % 86_400
    hms = f"{int(t // 3600):02d}{int(t % 3600 // 60):02d}{t % 60:05.2f}"
    lat, lat_sign = _dm(fix.lat, 2)
    lon, lon_sign = _dm(fix.lon, 3)
    ns, ew = ("N" if lat_sign > 0 else "S"), ("E" if lon_sign > 0 else "W")
    gga = f"GPGGA,{hms},{lat},{ns},{lon},{ew},{fix.quality},{fix.satellites:02d},0.9,{fix.alt:.2f},M,0.0,M,,"
    speed = math.hypot(fix.ve, fix.vn) / KNOT_M_S
    course = math.degrees(math.atan2(fix.ve, fix.vn)) % 360
    rmc = f"GPRMC,{hms},A,{lat},{ns},{lon},{ew},{speed:.3f},{course:.2f},010126,,,A"
    return _sentence(gga) + _sentence(rmc)


def _degrees(dm: str, hemi: str) -> float:
    dot = dm.index(".")
    value = float(dm[:dot - 2]) + float(dm[dot - 2:]) / 60.0
    return -value if hemi in ("S", "W") else value


class NmeaReader:
    """Feed bytes; get the fixes they complete. Bad sentences (checksum, shape, numbers) are counted."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.bad_sentences = 0
        self.sentences = 0
        self._gga: tuple[str, float, float, float, int, int] | None = None

    def feed(self, data: bytes) -> list[GpsFix]:
        self._buf += data
        out: list[GpsFix] = []
        while (end := self._buf.find(b"\n")) >= 0:
            line = bytes(self._buf[:end]).strip()
            del self._buf[:end + 1]
            fix = self._line(line)
            if fix is not None:
                out.append(fix)
        if len(self._buf) > MAX_LINE:
            self._buf.clear()
            self.bad_sentences += 1
        return out

    def _line(self, line: bytes) -> GpsFix | None:
        start = line.rfind(b"$")
        try:
            text = line[start:].decode("ascii") if start >= 0 else ""
            body, star, check = text[1:].partition("*")
            if not star or checksum(body) != check.upper():
                raise ValueError("checksum")
            f = body.split(",")
            if f[0].endswith("RMC") and len(f) >= 9:
                self.sentences += 1
                gga, self._gga = self._gga, None
                if f[2] != "A" or gga is None or gga[0] != f[1]:
                    return None
                speed = float(f[7]) * KNOT_M_S
                course = math.radians(float(f[8]))
                return GpsFix(lat=gga[1], lon=gga[2], alt=gga[3], ve=speed * math.sin(course),
                              vn=speed * math.cos(course), satellites=gga[5], quality=gga[4])
            if f[0].endswith("GGA") and len(f) >= 10:
                self.sentences += 1
                quality = int(f[6])
                self._gga = None if quality < 1 else (
                    f[1], _degrees(f[2], f[3]), _degrees(f[4], f[5]), float(f[9]), quality, int(f[7]))
                return None
            self.sentences += 1  # another sentence type: not ours, not an error
            return None
        except (ValueError, IndexError, UnicodeDecodeError):
            self.bad_sentences += 1
            return None


@dataclass(frozen=True)
class LocalGps:
    """A GPS measurement in the local frame (m, m/s): what the estimator takes."""

    east: float
    north: float
    up: float
    ve: float
    vn: float


class FakeGps:
    """The seed's test modes: ``zeros`` or ``random`` at ``rate_hz`` (1 Hz), in the local frame."""

    def __init__(self, mode: str, range_m: float = 5.0, rate_hz: float = 1.0, seed: int | None = None) -> None:
        if mode not in ("zeros", "random"):
            raise ValueError(f"fake GPS mode must be 'zeros' or 'random', not {mode!r}")
        self.mode = mode
        self.range_m = range_m
        self.period = 1.0 / rate_hz
        self._next = 0.0
        self._rng = random.Random(seed)

    def poll(self, now: float) -> LocalGps | None:
        if now < self._next:
            return None
        self._next = now + self.period if self._next == 0.0 else self._next + self.period
        if self.mode == "zeros":
            return LocalGps(0.0, 0.0, 0.0, 0.0, 0.0)
        r, v = self.range_m, self.range_m / 10
        u = self._rng.uniform
        return LocalGps(u(-r, r), u(-r, r), u(-r, r), u(-v, v), u(-v, v))
