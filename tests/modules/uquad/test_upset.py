"""Loss of control on the uQuad: the tumble rule (upset.py) with its clock, the flight core cutting the motors when
a motor fails in the in-process closed loop, and the simulator's fault-injection port over real TCP."""

from __future__ import annotations

import json
import math
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from modules.uquad import model
from modules.uquad.planner import Mode
from modules.uquad.sim.server import parse_control
from modules.uquad.upset import FallWatch, TumbleCut, tilt_deg

sys.path.insert(0, str(Path(__file__).resolve().parent))
from closed_loop import ROOT, ClosedLoop  # noqa: E402

R = math.radians


def test_tumble_rule_needs_the_tilt_for_hold_s_with_the_motors_on() -> None:
    cut = TumbleCut(max_tilt_deg=70.0, hold_s=0.1)
    assert not cut.update(0.00, R(80), 0.0, True)
    assert not cut.update(0.05, R(80), 0.0, True)
    assert not cut.update(0.08, R(20), 0.0, True)  # back under: the clock restarts
    assert not cut.update(0.10, R(0), R(75), True)
    assert cut.update(0.20, R(0), R(75), True)
    assert "tilted 75°" in cut.reason and "CUT_TILT_DEG 70°" in cut.reason
    assert not cut.update(0.30, R(170), 0.0, False)  # motors already off: nothing to cut
    assert not cut.update(0.50, R(170), 0.0, False)


def test_after_a_cut_the_quadrotor_is_falling_until_the_imu_shows_it_at_rest_for_rest_s() -> None:
    fall = FallWatch(rest_rate_rad_s=0.3, rest_acc_dev=0.1, rest_s=0.5)
    assert not fall.update(0.0, 0.0, 0.0)  # no cut: never falling
    fall.cut()
    assert fall.update(0.1, 0.0, -1.0)  # free fall reads 0 g
    assert fall.update(0.2, 5.0, 0.0)  # turning
    assert fall.update(0.3, 0.1, 0.02)  # still from here...
    assert fall.update(0.7, 0.1, 0.02)
    assert fall.update(0.75, 0.1, 0.5)  # ...a bounce: the wait starts again
    assert fall.update(0.8, 0.1, 0.02)
    assert fall.update(1.29, 0.1, 0.02)
    assert not fall.update(1.30, 0.1, 0.02)  # at rest for 0.5 s
    assert not fall.update(1.4, 5.0, -1.0)  # carried away afterwards: no cut, not a fall


def test_upside_down_is_tilted_however_roll_and_pitch_share_it() -> None:
    assert tilt_deg(R(180), 0.0) == pytest.approx(180.0)
    assert tilt_deg(R(50), R(50)) == pytest.approx(math.degrees(math.acos(math.cos(R(50)) ** 2)))
    assert tilt_deg(R(-100), R(0)) == pytest.approx(100.0)


def test_a_motor_lost_in_hover_is_cut_soon_after_the_truth_tilts_and_stays_off() -> None:
    loop = ClosedLoop()
    loop.run(5.3)  # the start calibration (512 frames standing still)
    assert loop.core.calibrated
    loop.core.planner.takeoff_height = 2.0
    loop.core.set_mode(Mode.TAKE_OFF)
    loop.run(5.5)
    assert loop.sim.x[model.IZ] > 1.5 and loop.core.stats.tumble_cuts == 0
    loop.sim.fail_motor(1, 0.0)
    failed_at = loop.t
    tilted_at = cut_at = None
    for _ in range(150):
        loop.run(0.01)
        x = loop.sim.x
        if tilted_at is None and tilt_deg(x[model.IPSI], x[model.IPHI]) > 45.0:
            tilted_at = loop.t
        if cut_at is None and loop.core.stats.tumble_cuts:
            cut_at = loop.t
            assert not np.any(loop.core.last_command)  # the stop command, at once
        if cut_at is not None and not loop.sim.on_ground:
            assert loop.core.fall.falling, f"in the air {loop.t - cut_at:.2f} s after the cut, not reported falling"
    assert tilted_at is not None and cut_at is not None, "the quadrotor must tumble and be cut"
    assert cut_at - tilted_at < 0.4, (tilted_at - failed_at, cut_at - failed_at)
    assert loop.core.planner.mode is Mode.IDLE and loop.core.stats.tumble_cuts == 1
    assert loop.sim.on_ground and not np.any(loop.sim.w > 1.0), "on the ground with the motors stopped"
    assert not loop.core.fall.falling, "at rest on the ground: no longer reported falling"
    loop.core.set_mode(Mode.LAND)  # a landing asked after the cut finds it on the ground: nothing starts
    loop.run(0.5)
    assert loop.core.planner.mode is Mode.IDLE and not np.any(loop.sim.w > 1.0)


@pytest.mark.parametrize("line,why", [
    (b'{"motor": 4, "efficiency": 0}', "motor must be an integer 0..3"),
    (b'{"motor": 1, "efficiency": 1.5}', "efficiency must be a number in [0, 1]"),
    (b'{"motor": true, "efficiency": 0}', "motor must be an integer"),
    (b'{"motor": 1}', "expected"),
    (b"motor 1 off", "not JSON"),
])
def test_control_lines_refused_with_the_reason(line: bytes, why: str) -> None:
    with pytest.raises(ValueError, match=re.escape(why)):
        parse_control(line)
    assert parse_control(b'{"motor": 2, "efficiency": 0.25}') == (2, 0.25)


def test_fault_injection_port_of_the_simulator_process() -> None:
    """``python -m modules.uquad.sim --control``: a refused line changes nothing, a motor failure shows in the
    truth stream from then on."""
    proc = subprocess.Popen([sys.executable, "-m", "modules.uquad.sim", "--conf",
                             str(ROOT / "bbcs_conf" / "uquad1.conf"), "--gps", "none", "--control", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, text=True, cwd=ROOT)
    socks: list[socket.socket] = []
    try:
        ready = proc.stdout.readline()
        port = {name: int(p) for name, p in re.findall(r"(\w+)=tcp://127.0.0.1:(\d+)", ready)}
        control = socket.create_connection(("127.0.0.1", port["control"]), timeout=10)
        truth = socket.create_connection(("127.0.0.1", port["truth"]), timeout=10)
        socks += [control, truth]
        replies = control.makefile("rb")
        control.sendall(b'{"motor": 7, "efficiency": 0}\n')
        assert json.loads(replies.readline()) == {"ok": False, "error": "motor must be an integer 0..3, not 7"}
        control.sendall(b'{"motor": 3, "efficiency": 0.0}\n')
        answer = json.loads(replies.readline())
        assert answer["ok"] is True and answer["t"] >= 0.0  # 0: before the first step
        lines = truth.makefile("rb")
        end = time.monotonic() + 10
        while time.monotonic() < end:
            doc = json.loads(lines.readline())
            if doc["t"] > answer["t"]:
                assert doc["motor_efficiency"] == [1.0, 1.0, 1.0, 0.0]
                break
        else:
            pytest.fail("no truth line after the failure")
    finally:
        for s in socks:
            s.close()
        proc.terminate()
        proc.wait(10)
