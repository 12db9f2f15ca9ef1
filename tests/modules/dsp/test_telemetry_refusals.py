"""Issue 30 case 3: a telemetry frame that passes the CRC but has a field outside the range its type declares (or
does not decode) is refused by one rule for every field, counted one by one, and reported in bounded number."""

from __future__ import annotations

import math
import os
import struct
from itertools import accumulate

import msgspec
import pytest

from bbcs.contracts import dsp as p
from bbcs.testing import wait_until
from modules.dsp import codec
from modules.dsp.codec import _encode_telemetry as encode_unchecked
from modules.dsp.framing import build_frame
from modules.dsp.link import DspLink
from modules.dsp.refusals import Refusal, RefusalCounter

from .test_link import FarEnd

GOOD = p.Telemetry(
    time_ms=1,
    position=p.TelPosition(lat=37.4117, lon=-6.0025, alt=22.0),
    attitude=p.TelAttitude(roll=1.0, pitch=-2.0, yaw=179.5),
    velocity=p.TelVelocity(vn=1.0, ve=0.5, vd=0.0),
    angular_rate=p.AngularRate(p=0.0, q=0.0, r=3.0),
    heading=-180.0,
    status=p.DspStatus(mode=6, tracking=True, path_valid=True, airborne=True, queue_length=512),
    nav=p.NavTarget(lat=37.4118, lon=-6.0025, alt=22.0, distance=-1.0),
    speed=p.SpeedInfo(commanded=30.0, ground=5.0),
    pan_tilt=p.PanTiltState(mode=2, pan=180.0, tilt=-90.0),
    error_code=0,
    engine=p.Engine(rotor_rpm=1500.0, battery_v=24.0),
)
"""A frame with every field, several at the edge of their range (all accepted)."""


def spoilt(path: str, value: float | int) -> p.Telemetry:
    """GOOD with one member replaced, unchecked (what a damaged frame that passed the CRC carries)."""
    name, _, member = path.partition(".")
    part = getattr(GOOD, name)
    return msgspec.structs.replace(GOOD, **{name: msgspec.structs.replace(part, **{member: value}) if member
                                            else value})


BAD_FIELDS = [
    ("position.lat", 200.0), ("position.lon", -180.5), ("position.alt", 12_000.0), ("attitude.roll", math.inf),
    ("attitude.pitch", 90.5), ("attitude.yaw", 180.0), ("velocity.vd", 151.0), ("angular_rate.q", -2001.0),
    ("heading", 180.0), ("heading", math.nan), ("status.mode", 9), ("status.queue_length", 600),
    ("status.reserved_flags", 8), ("nav.distance", -2.0), ("speed.commanded", 30.5), ("speed.ground", -0.5),
    ("pan_tilt.mode", 5), ("pan_tilt.tilt", 91.0), ("engine.rotor_rpm", 5001.0), ("engine.battery_v", -1.0),
]


def test_a_frame_at_the_edges_of_every_range_is_accepted_after_the_wire() -> None:
    back = codec.decode_payload(p.MsgId.TELEMETRY, codec.encode_payload(GOOD))
    p.check(back)
    assert back.heading == -180.0 and back.status.queue_length == 512 and back.attitude.yaw < 180.0  # type: ignore[union-attr]
    almost = math.nextafter(180.0, 0.0)  # a double below 180 that binary32 would round up to 180.0
    back = codec.decode_payload(p.MsgId.TELEMETRY, codec.encode_payload(p.Telemetry(time_ms=0, heading=almost)))
    assert back.heading is not None and back.heading < 180.0  # type: ignore[attr-defined]


@pytest.mark.parametrize(("path", "value"), BAD_FIELDS, ids=[f"{f}={v}" for f, v in BAD_FIELDS])
def test_every_field_outside_its_declared_range_is_refused_naming_it(path: str, value: float) -> None:
    payload = encode_unchecked(spoilt(path, value))  # good CRC: only the range check can catch it
    back = codec.decode_payload(p.MsgId.TELEMETRY, payload)  # decoding never refuses a value
    with pytest.raises(p.DspValueError) as info:
        p.check(back)
    assert info.value.field == path
    assert f"Telemetry.{path}=" in str(info.value)


def test_the_wire_bytes_of_the_issue_are_refused() -> None:
    """The bytes themselves: STATUS mode 9, flags bit 3, queue 600; PAN_TILT mode 5; HEADING 180.0."""
    status, pan_tilt, heading = (int(f) for f in (p.TelemetryField.STATUS, p.TelemetryField.PAN_TILT,
                                                  p.TelemetryField.HEADING))
    cases = {
        "status.mode": struct.pack("<IIBBH", 0, status, 9, 0, 0),
        "status.reserved_flags": struct.pack("<IIBBH", 0, status, 0, 0b1000, 0),
        "status.queue_length": struct.pack("<IIBBH", 0, status, 0, 0, 600),
        "pan_tilt.mode": struct.pack("<IIBff", 0, pan_tilt, 5, 0.0, 0.0),
        "heading": struct.pack("<IIf", 0, heading, 180.0),
    }
    for field, payload in cases.items():
        with pytest.raises(p.DspValueError) as info:
            p.check(codec.decode_payload(p.MsgId.TELEMETRY, payload))
        assert info.value.field == field


# --- the link: refused frames never reach on_telemetry, each one counted --------------------------------------


def test_the_link_drops_and_counts_each_refused_frame_and_delivers_the_good_ones() -> None:
    far = FarEnd(lambda frame: b"")
    good: list[p.Telemetry] = []
    refused: list[Refusal] = []
    try:
        with DspLink(far.path, on_telemetry=good.append, on_refused=refused.append) as link:
            _stream_good_and_bad(far)
            wait_until(lambda: len(refused) == len(BAD_FIELDS) + 1, what="every bad frame refused")
            wait_until(lambda: len(good) == len(BAD_FIELDS), what="every good frame delivered")
            stats = link.stats()
    finally:
        far.close()
    assert [r.field for r in refused] == [f for f, _ in BAD_FIELDS] + ["frame"]
    assert "reserved bits" in refused[-1].detail
    assert stats.telemetry_refused == len(BAD_FIELDS) + 1
    assert stats.telemetry_frames == len(BAD_FIELDS) and "reserved bits" in stats.last_refused
    assert [t.time_ms for t in good] == list(range(len(BAD_FIELDS)))
    assert all(t == msgspec.structs.replace(GOOD, time_ms=t.time_ms) for t in good)


def _stream_good_and_bad(far: FarEnd) -> None:
    """A good frame, then the next bad one, for every bad field; then one malformed frame."""
    stream = b""
    seq = 0
    for i, (path, value) in enumerate(BAD_FIELDS):
        for msg in (msgspec.structs.replace(GOOD, time_ms=i), spoilt(path, value)):
            stream += build_frame(int(p.MsgId.TELEMETRY), seq, encode_unchecked(msg))
            seq = (seq + 1) & 0xFF
    # a malformed frame: 8 bytes (a valid telemetry length) whose mask has reserved bits
    stream += build_frame(int(p.MsgId.TELEMETRY), seq, struct.pack("<II", 0, 1 << 12))
    os.write(far.master, stream)


# --- coalescing: one report for one frame, a bounded number for a flood, every frame counted --------------------


def test_one_bad_frame_is_reported_at_once_and_only_once() -> None:
    counter = RefusalCounter(period_s=1.0)
    report = counter.refuse(Refusal("position.lat", "Telemetry.position.lat=200.0 is out of range"), 10.0)
    assert report is not None and report.frames == 1 and report.total == 1
    assert report.by_field == (("position.lat", 1),)
    assert "1 telemetry frame refused (position.lat 1)" in report.text()
    assert [counter.flush(t) for t in (10.5, 11.0, 30.0)] == [None, None, None]
    assert counter.reports == 1


def test_a_flood_of_ten_thousand_bad_frames_gives_a_bounded_number_of_reports_with_exact_counts() -> None:
    counter = RefusalCounter(period_s=1.0)
    reports = []
    fields = ("position.lat", "heading", "status.mode")
    for i in range(10_000):  # 10,000 frames at 1 kHz: 10 s of flood
        now = 100.0 + i * 0.001
        report = counter.refuse(Refusal(fields[i % 3], f"frame {i}"), now)
        if report is not None:
            reports.append((now, report))
        if i % 250 == 0:  # the process's tick flushes too
            report = counter.flush(now)
            if report is not None:
                reports.append((now, report))
    end = 100.0 + 10.0
    while counter.pending:  # quiet again: the tick reports what is left within a period
        end += 0.25
        report = counter.flush(end)
        if report is not None:
            reports.append((end, report))
    assert 10 <= len(reports) <= 12  # at most one a second, plus the first
    times = [t for t, _ in reports]
    assert all(b - a >= 1.0 - 1e-9 for a, b in zip(times, times[1:], strict=False))
    assert sum(r.frames for _, r in reports) == 10_000 == counter.total
    assert [r.total for _, r in reports] == list(accumulate(r.frames for _, r in reports))
    by_field: dict[str, int] = {}
    for _, r in reports:
        for name, n in r.by_field:
            by_field[name] = by_field.get(name, 0) + n
    assert by_field == {"position.lat": 3334, "heading": 3333, "status.mode": 3333}
    assert reports[-1][1].last == "frame 9999"


def test_a_bad_frame_after_a_quiet_period_is_reported_at_once_again() -> None:
    counter = RefusalCounter(period_s=1.0)
    assert counter.refuse(Refusal("heading", "a"), 0.0) is not None
    assert counter.refuse(Refusal("heading", "b"), 0.2) is None  # within the period: counted, held
    late = counter.flush(1.0)
    assert late is not None and late.frames == 1 and late.total == 2
    again = counter.refuse(Refusal("heading", "c"), 5.0)
    assert again is not None and again.frames == 1 and again.total == 3
    with pytest.raises(ValueError):
        RefusalCounter(period_s=0.0)
