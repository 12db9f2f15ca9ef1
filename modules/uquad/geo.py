"""Local east-north-up metres around a home point ↔ WGS84 degrees (equirectangular: cm-accurate over a few km)."""

from __future__ import annotations

import math
from dataclasses import dataclass

EARTH_RADIUS_M = 6_371_000.0


@dataclass(frozen=True)
class Home:
    lat: float
    lon: float
    alt: float

    def to_local(self, lat: float, lon: float, alt: float) -> tuple[float, float, float]:
        east = math.radians(lon - self.lon) * EARTH_RADIUS_M * math.cos(math.radians(self.lat))
        north = math.radians(lat - self.lat) * EARTH_RADIUS_M
        return east, north, alt - self.alt

    def to_geo(self, east: float, north: float, up: float) -> tuple[float, float, float]:
        lat = self.lat + math.degrees(north / EARTH_RADIUS_M)
        lon = self.lon + math.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(self.lat))))
        return lat, lon, self.alt + up
