import math

import numpy as np
import pytest

from modules.vision.geodesy import LocalFrame, check_lla, wrap_deg, wrap_lon


def test_degree_lengths_match_wgs84_series_at_45_degrees():
    # Independent textbook series for the length of one degree on WGS84.
    phi = math.radians(45.0)
    lat_deg_m = 111132.954 - 559.822 * math.cos(2 * phi) + 1.175 * math.cos(4 * phi)
    lon_deg_m = 111412.84 * math.cos(phi) - 93.5 * math.cos(3 * phi) + 0.118 * math.cos(5 * phi)
    frame = LocalFrame(45.0, 10.0, 0.0)
    north = frame.to_enu(45.001, 10.0, 0.0)[1] * 1000.0
    east = frame.to_enu(45.0, 10.001, 0.0)[0] * 1000.0
    assert north == pytest.approx(lat_deg_m, rel=1e-4)
    assert east == pytest.approx(lon_deg_m, rel=1e-4)


def test_round_trip_is_exact_for_arrays():
    frame = LocalFrame(37.41, -6.0, 12.0)
    rng = np.random.default_rng(1)
    enu = rng.uniform(-2000, 2000, size=(100, 3))
    back = frame.to_enu(*frame.to_lla(enu).T)
    np.testing.assert_allclose(back, enu, atol=1e-6)


def test_up_is_altitude_minus_reference():
    frame = LocalFrame(10.0, 20.0, 100.0)
    assert frame.to_enu(10.0, 20.0, 130.0).tolist() == [0.0, 0.0, 30.0]
    assert frame.to_lla([0.0, 0.0, -100.0]).tolist() == [10.0, 20.0, 0.0]


def test_longitude_wraps_across_the_antimeridian():
    frame = LocalFrame(0.0, 179.9999, 0.0)
    east = frame.to_enu(0.0, -179.9999, 0.0)[0]
    assert east == pytest.approx(2 * 0.0001 * 111319.49, rel=1e-4)
    lla = frame.to_lla([50.0, 0.0, 0.0])
    assert -180.0 <= lla[1] < 180.0
    assert lla[1] < 0.0  # went past +180 and wrapped


def test_latitude_past_a_pole_is_refused():
    frame = LocalFrame(88.9, 0.0, 0.0)
    with pytest.raises(ValueError, match="latitude"):
        frame.to_lla([0.0, 200_000.0, 0.0])


@pytest.mark.parametrize(
    ("lat", "lon", "alt", "field"),
    [
        (91.0, 0.0, 0.0, "latitude"),
        (0.0, 180.5, 0.0, "longitude"),
        (0.0, 0.0, math.nan, "altitude"),
        (math.inf, 0.0, 0.0, "latitude"),
    ],
)
def test_bad_positions_name_the_field(lat, lon, alt, field):
    with pytest.raises(ValueError, match=field):
        check_lla(lat, lon, alt)


def test_reference_near_pole_is_refused():
    with pytest.raises(ValueError, match="pole"):
        LocalFrame(89.5, 0.0, 0.0)


def test_wrappers():
    assert wrap_lon(190.0) == -170.0
    assert wrap_lon(-180.0) == -180.0
    assert wrap_deg(180.0) == 180.0
    assert wrap_deg(540.0) == 180.0
    assert wrap_deg(-190.0) == 170.0
    assert wrap_deg(-180.0) == -180.0
