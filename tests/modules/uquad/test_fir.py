"""The seed's raw-data queue and FIR filter (seed 002 §1.3, equation 1.3), against hand-computed values."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bbcs.conf import ConfError
from modules.uquad.config import load_config
from modules.uquad.fir import SEED_COEFFS, RawQueue, fir
from modules.uquad.imu_protocol import ImuFrame
from modules.uquad.planner import Mode

from .closed_loop import ROOT, ClosedLoop


def frame(k: float, loop_us: int = 10_000) -> ImuFrame:
    v = int(k)
    return ImuFrame(loop_us, (v, 2 * v, 3 * v), (v, 0, -v), (0, v, 0), 250 + v, 101_325 + v)


def test_equation_1_3_by_hand() -> None:
    x = np.array([[1.0], [2.0], [3.0], [4.0], [5.0], [6.0]])  # oldest first: x[n] = 6
    # 0.2·6 + 0.2·5 + 0.2·4 + 0.2·3 + 0.1·2 + 0.1·1 = 3.6 + 0.3
    assert fir(x, SEED_COEFFS) == pytest.approx([3.9])
    assert fir(np.vstack([np.full((3, 1), 100.0), x]), SEED_COEFFS) == pytest.approx([3.9])  # only the 6 newest


def test_coefficients_make_it_a_pass_through_or_an_average() -> None:
    x = np.array([[1.0, 10.0], [3.0, 30.0], [8.0, 80.0]])
    assert fir(x, [1.0]) == pytest.approx([8.0, 80.0])
    assert fir(x, [1 / 3] * 3) == pytest.approx([4.0, 40.0])
    with pytest.raises(ValueError, match="3 coefficients need 3 samples"):
        fir(x[:2], [1 / 3] * 3)
    with pytest.raises(ValueError, match="at least one"):
        fir(x, [])


def test_queue_filters_the_most_recent_frames_and_wraps() -> None:
    q = RawQueue(8)
    for k in range(1, 6):
        q.push(frame(k))
        assert q.filtered() is None  # not enough frames for six coefficients yet
    for k in range(6, 20):  # wraps round the 8-row queue
        q.push(frame(k, loop_us=k))
    y = q.filtered()
    assert y is not None
    # newest 19..14: 0.2·(19+18+17+16) + 0.1·(15+14) = 14 + 2.9 = 16.9 for every field equal to k
    assert y.acc == pytest.approx((16.9, 33.8, 50.7)) and y.gyro == pytest.approx((16.9, 0.0, -16.9))
    assert y.temp_x10 == pytest.approx(266.9) and y.pressure_pa == pytest.approx(101_341.9)
    assert y.loop_us == 19


def test_newest_unused_is_handed_out_once_and_a_late_loop_skips_to_the_newest() -> None:
    q = RawQueue(8)
    assert q.newest_unused() is None
    q.push(frame(1))
    assert q.newest_unused().acc == (1.0, 2.0, 3.0)  # type: ignore[union-attr]
    assert q.newest_unused() is None
    for k in (2, 3, 4):  # the main loop fell behind: 2 and 3 are never "the newest" ...
        q.push(frame(k))
    assert q.newest_unused().acc == (4.0, 8.0, 12.0)  # type: ignore[union-attr]
    assert q.count == 4  # ... but they are in the queue, for the filter


def test_queue_must_be_longer_than_the_filter(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="longer than the filter"):
        RawQueue(6)
    conf = ROOT / "bbcs_conf" / "uquad1.conf"
    text = conf.read_text().replace("IMU_FIR: []", "IMU_FIR: [0.2 0.2 0.2 0.2 0.1 0.1]")
    bad = tmp_path / "uquad1.conf"
    bad.write_text(text.replace("IMU_QUEUE_LEN: 16", "IMU_QUEUE_LEN: 4"))
    for name in ("uquad1_imu_calib.conf", "uquad1_K_prop.txt", "uquad1_K_int.txt"):
        (tmp_path / name).write_text((conf.parent / name).read_text())
    with pytest.raises(ConfError) as err:
        load_config(bad)
    line = text.splitlines().index("IMU_QUEUE_LEN: 16") + 1
    assert "IMU_QUEUE_LEN (4)" in str(err.value) and err.value.line == line and str(bad) in str(err.value)


def test_filter_on_in_flight_still_calibrates_and_hovers() -> None:
    loop = ClosedLoop(seed=5)
    loop.core.raw_queue = RawQueue(16, SEED_COEFFS)
    loop.run(5.5)
    assert loop.core.calibrated
    loop.core.set_mode(Mode.TAKE_OFF)
    loop.run(14.0)
    assert "take_off" in loop.core.planner.completed
    assert abs(loop.sim.x[2] - 3.0) < 0.5
