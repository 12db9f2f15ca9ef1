"""The uQuad's home: the local east-north-up frame its controller flies in, in the project's geodesy
(:mod:`bbcs.geodesy`, WGS84 linearised at home: cm-accurate over a few km)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

from bbcs.geodesy import LocalFrame


@dataclass(frozen=True)
class Home:
    lat: float
    lon: float
    alt: float

    @cached_property
    def frame(self) -> LocalFrame:
        return LocalFrame(self.lat, self.lon, self.alt)

    def to_local(self, lat: float, lon: float, alt: float) -> tuple[float, float, float]:
        """East, north, up metres from home."""
        return self.frame.to_local(lat, lon, alt)

    def to_geo(self, east: float, north: float, up: float) -> tuple[float, float, float]:
        """Latitude, longitude, altitude of a local point."""
        return self.frame.to_geo(east, north, up)
