"""NMEA reader against hand-written sentences; fake modes."""

import pytest

from modules.uquad.gps import FakeGps, GpsFix, NmeaReader, checksum, encode

GGA = b"$GPGGA,123519.00,4807.0380,N,01131.0000,E,1,08,0.9,545.40,M,46.9,M,,"
RMC = b"$GPRMC,123519.00,A,4807.0380,N,01131.0000,E,10.000,90.00,230394,,,A"


def line(body: bytes) -> bytes:
    return body + b"*" + checksum(body[1:].decode()).encode() + b"\r\n"


def test_fix_from_gga_then_rmc_by_hand():
    r = NmeaReader()
    assert r.feed(line(GGA)) == []
    (fix,) = r.feed(line(RMC))
    assert fix.lat == pytest.approx(48 + 7.038 / 60) and fix.lon == pytest.approx(11 + 31 / 60)
    assert fix.alt == 545.4 and fix.satellites == 8
    assert fix.ve == pytest.approx(5.14444) and fix.vn == pytest.approx(0, abs=1e-9)  # 10 kn due east


def test_bad_checksum_garbage_and_no_fix_are_dropped():
    r = NmeaReader()
    bad = line(GGA).replace(b"545.40", b"545.41")  # checksum no longer matches
    nofix = line(GGA.replace(b",1,08,", b",0,08,"))
    assert r.feed(b"\x00\xffnoise\r\n" + bad + line(RMC) + nofix + line(RMC)) == []
    assert r.bad_sentences == 2


def test_encode_round_trip_south_west():
    fix = GpsFix(lat=-34.918, lon=-56.166, alt=30.5, ve=1.0, vn=-2.0, satellites=9, quality=1)
    (got,) = NmeaReader().feed(encode(fix, 3600.0))
    assert got.lat == pytest.approx(fix.lat, abs=1e-6) and got.lon == pytest.approx(fix.lon, abs=1e-6)
    assert (got.ve, got.vn) == pytest.approx((1.0, -2.0), abs=0.01)


def test_fake_modes_at_one_hertz():
    zeros = FakeGps("zeros")
    samples = [zeros.poll(t / 10) for t in range(31)]
    assert sum(s is not None for s in samples) == 4  # t = 0, 1, 2, 3
    assert all(v == 0 for v in vars(samples[0]).values())
    rnd = FakeGps("random", range_m=2.0, seed=1)
    values = [rnd.poll(float(t)) for t in range(50)]
    assert all(abs(v.east) <= 2 and abs(v.ve) <= 0.2 for v in values) and len({v.east for v in values}) == 50
    with pytest.raises(ValueError):
        FakeGps("ones")
