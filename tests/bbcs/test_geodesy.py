"""The one Earth model: its local frame, distances, bearings and offsets against exact WGS84 (ECEF), which the
same module computes independently of the linearisation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bbcs.geodesy import (
    LocalFrame,
    bearing_deg,
    check_lla,
    distance_m,
    ecef_from_enu,
    ecef_to_lla,
    lla_to_ecef,
    metres_per_degree,
    offset,
)

SEVILLE = (37.4117, -6.0025)


def _exact_enu(lat0: float, lon0: float, lat: float, lon: float) -> np.ndarray:
    """East/north/up of (lat, lon) on the tangent plane at (lat0, lon0), from ECEF: no linearisation."""
    d = lla_to_ecef(np.array([lat, lon, 0.0])) - lla_to_ecef(np.array([lat0, lon0, 0.0]))
    return d @ ecef_from_enu(lat0, lon0)


def test_degree_lengths_match_the_textbook_wgs84_series() -> None:
    phi = math.radians(45.0)
    lat_deg_m = 111132.954 - 559.822 * math.cos(2 * phi) + 1.175 * math.cos(4 * phi)
    lon_deg_m = 111412.84 * math.cos(phi) - 93.5 * math.cos(3 * phi) + 0.118 * math.cos(5 * phi)
    north, east = metres_per_degree(45.0)
    assert north == pytest.approx(lat_deg_m, rel=1e-5) and east == pytest.approx(lon_deg_m, rel=1e-5)


@pytest.mark.parametrize(("north", "east"), [(1000.0, 0.0), (0.0, 1000.0), (-700.0, 700.0), (2000.0, -1500.0)])
def test_the_local_frame_agrees_with_exact_geodesy_within_d2_over_r(north: float, east: float) -> None:
    frame = LocalFrame(*SEVILLE)
    lat, lon, _ = frame.to_geo(east, north)
    exact = _exact_enu(*SEVILLE, lat, lon)
    d = math.hypot(north, east)
    assert math.hypot(exact[0] - east, exact[1] - north) < d * d / 6.3e6 + 1e-3
    assert distance_m(*SEVILLE, lat, lon) == pytest.approx(math.hypot(exact[0], exact[1]), abs=d * d / 6.3e6 + 1e-3)


def test_round_trips_are_exact_for_floats_and_arrays() -> None:
    frame = LocalFrame(*SEVILLE, 12.0)
    e, n, u = frame.to_local(*frame.to_geo(123.4, -567.8, 9.0))
    assert (e, n, u) == pytest.approx((123.4, -567.8, 9.0), abs=1e-9)
    en = np.random.default_rng(3).uniform(-3000, 3000, size=(50, 3))
    np.testing.assert_allclose(frame.to_enu(*frame.to_lla(en).T), en, atol=1e-6)


def test_bearings_point_the_way_offsets_go() -> None:
    for north, east, expected in [(100, 0, 0.0), (0, 100, 90.0), (-100, 0, -180.0), (0, -100, -90.0), (50, 50, 45.0)]:
        lat, lon = offset(*SEVILLE, north, east)
        assert bearing_deg(*SEVILLE, lat, lon) == pytest.approx(expected, abs=1e-3)  # mean vs start latitude
        assert distance_m(*SEVILLE, lat, lon) == pytest.approx(math.hypot(north, east), rel=1e-5)


def test_ecef_round_trip_and_the_antimeridian() -> None:
    lla = np.array([[37.4, -6.0, 120.0], [-33.9, 151.2, 5.0]])
    np.testing.assert_allclose(ecef_to_lla(lla_to_ecef(lla)), lla, atol=1e-7)
    frame = LocalFrame(0.0, 179.9999)
    assert frame.to_local(0.0, -179.9999)[0] == pytest.approx(0.0002 * metres_per_degree(0.0)[1], rel=1e-9)


@pytest.mark.parametrize(("lat", "lon", "alt", "name"), [(91.0, 0.0, 0.0, "latitude"), (0.0, 180.5, 0.0, "longitude"),
                                                          (0.0, 0.0, math.nan, "altitude"),
                                                          (math.inf, 0.0, 0.0, "latitude")])
def test_a_bad_position_is_refused_naming_its_field(lat: float, lon: float, alt: float, name: str) -> None:
    with pytest.raises(ValueError, match=name):
        check_lla(lat, lon, alt)
    with pytest.raises(ValueError, match=name):
        LocalFrame(lat, lon, alt)


def test_a_frame_at_a_pole_and_a_point_past_it_are_refused() -> None:
    with pytest.raises(ValueError, match="pole"):
        LocalFrame(89.5, 0.0)
    with pytest.raises(ValueError, match="latitude"):
        LocalFrame(88.9, 0.0).to_lla([0.0, 200_000.0, 0.0])


def test_the_reference_maps_to_itself_exactly() -> None:
    """A simulator at home reports home to the digit (a modulo on an in-range longitude would round it)."""
    frame = LocalFrame(37.4117, -6.0025, 12.0)
    assert frame.to_geo(0.0, 0.0, 0.0) == (37.4117, -6.0025, 12.0)
    assert frame.to_local(37.4117, -6.0025, 12.0) == (0.0, 0.0, 0.0)
