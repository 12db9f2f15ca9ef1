"""Fault injection: rates honoured, repeatable with a seed, intact frames told apart from damaged ones."""

from __future__ import annotations

import numpy as np
import pytest

from bbcs.contracts import dsp as p
from modules.dsp.sim.faults import FaultInjector, garble
from modules.dsp.sim.stress import dsp_traffic, fault_stream


def test_rates_are_roughly_honoured_and_repeatable() -> None:
    data = bytes(range(256)) * 400
    a = FaultInjector(corrupt=0.01, drop=0.005, seed=3)
    b = FaultInjector(corrupt=0.01, drop=0.005, seed=3)
    out_a, intact = a.apply_frame(data)
    assert out_a == b.apply(data) and not intact
    assert 0.008 < a.counts.bytes_corrupted / len(data) < 0.012
    assert 0.003 < a.counts.bytes_dropped / len(data) < 0.007
    assert len(out_a) == len(data) - a.counts.bytes_dropped


def test_no_faults_means_untouched() -> None:
    inj = FaultInjector()
    assert not inj.active
    assert inj.apply_frame(b"abc") == (b"abc", True)


def test_garbage_bursts_with_false_headers() -> None:
    inj = FaultInjector(garbage=1.0, seed=1, false_ids={p.MsgId.TELEMETRY: 107})
    outs = [inj.apply_frame(b"FRAME") for _ in range(200)]
    assert all(out.endswith(b"FRAME") and ok for out, ok in outs)
    assert inj.counts.garbage_bursts == 200
    assert 60 < inj.counts.false_headers < 140
    assert sum(out.startswith(bytes([0xA5, 0x5A, 107, p.MsgId.TELEMETRY])) for out, _ in outs) >= \
        inj.counts.false_headers


def test_bad_rates_are_refused() -> None:
    with pytest.raises(ValueError):
        FaultInjector(corrupt=1.5)
    with pytest.raises(ValueError):
        FaultInjector(burst_max=0)


def test_fault_stream_marks_exactly_the_damaged_frames() -> None:
    frames = dsp_traffic(2000, seed=9)
    damaged = fault_stream(frames, corrupt=0.01, drop=0.0, garbage=0.0, seed=10)
    stream = damaged.stream
    pos = 0
    for frame, ok in zip(frames, damaged.intact, strict=True):
        piece = stream[pos:pos + len(frame)]
        assert (piece == frame) == bool(ok)
        pos += len(frame)
    assert pos == len(stream)


def test_garble_length_follows_the_baud_ratio() -> None:
    rng = np.random.default_rng(0)
    assert len(garble(bytes(1000), rng, 0.125)) == 125
    assert len(garble(bytes(100), rng, 8.0)) == 100
    assert garble(b"", rng, 1.0) == b""
