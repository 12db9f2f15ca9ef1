"""The geographic and angle types carry their ranges: decoding a struct that uses them is validating it."""

from __future__ import annotations

import math

import msgspec
import pytest

from bbcs.contracts import geo


class Sample(msgspec.Struct):
    lat: geo.Latitude
    lon: geo.Longitude
    alt: geo.AltitudeAMSL
    pan: geo.DegreesSigned180
    tilt: geo.DegreesSigned90
    heading: geo.HeadingDegrees
    rad: geo.Radians


GOOD = {"lat": 37.4, "lon": -6.0, "alt": 12.0, "pan": 180.0, "tilt": -90.0, "heading": -180.0, "rad": -math.pi}


def test_values_at_the_limits_decode():
    assert msgspec.convert(GOOD, Sample).pan == 180.0


@pytest.mark.parametrize("field,value", [("lat", 90.001), ("lon", -180.5), ("alt", 10_001.0), ("pan", 181.0),
                                         ("tilt", -90.5), ("heading", 180.0), ("rad", math.pi)])
def test_each_range_is_enforced(field, value):
    with pytest.raises(msgspec.ValidationError, match=rf"\$\.{field}"):
        msgspec.convert({**GOOD, field: value}, Sample)


def test_geopoint_refuses_a_latitude_beyond_90():
    with pytest.raises(msgspec.ValidationError):
        msgspec.msgpack.decode(msgspec.msgpack.encode({"lat": 95.0, "lon": 0.0, "alt": 0.0}), type=geo.GeoPoint)
