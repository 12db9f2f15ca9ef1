"""The lidar simulators flying with the DSP simulator's aircraft (``sim/follow.py``, the truth link)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from bbcs.contracts.vehicle_truth import VehicleTruth, decode_truth, encode_truth
from bbcs.geodesy import LocalFrame
from bbcs.testing import wait_until
from modules.dsp.sim.machine import DspMachine
from modules.dsp.sim.truth import TruthSender
from modules.lidar_logger.sim.follow import FollowClock, FollowedFlight, TruthReceiver
from modules.lidar_logger.sim.world import World

HOME = (37.4117, -6.0025, 12.0)
FRAME = LocalFrame(*HOME)
"""The DSP simulator's frame at home (bbcs.geodesy), in which these flights are written."""


def truth(t: float, *, seq: int = 0, roll: float = 3.0, pitch: float = -4.0, heading: float = 30.0,
          v: tuple[float, float, float] = (4.0, 2.0, 0.5)) -> VehicleTruth:
    """The aircraft at time ``t`` moving at constant velocity ``v`` (north, east, up) from 20 m above home."""
    n, e, u = (c * t for c in v)
    return VehicleTruth(seq=seq, time_s=t, time_scale=4.0, home=HOME, lat=FRAME.to_geo(e, n)[0],
                        lon=FRAME.to_geo(e, n)[1], alt=HOME[2] + 20.0 + u,
                        vel_neu=v, roll=roll, pitch=pitch, heading=heading)


def test_truth_datagram_round_trips_and_bad_ranges_are_refused() -> None:
    t = truth(3.0, seq=7)
    assert decode_truth(encode_truth(t)) == t
    bad = encode_truth(t).replace(encode_truth(t)[-9:], encode_truth(truth(3.0, heading=0.0))[-9:])
    assert decode_truth(bad).heading == 0.0  # the field really is the heading: the test below changes it
    with pytest.raises(Exception, match="heading|Expected|<="):
        decode_truth(encode_truth(t)[:-9] + b"\xcb" + np.float64(400.0).byteswap().tobytes())


def test_followed_flight_anchors_the_world_at_home_and_reports_the_aircraft_as_an_mtig_would() -> None:
    world = World(clock=FollowClock())
    world.flight = FollowedFlight(None, on_anchor=world.set_origin)
    for k in range(11):
        world.flight.add(truth(k * 0.02, seq=k))
    assert world.origin_lla == HOME
    pos, vel, rot = world.flight.state(np.array([0.0, 0.1, 0.2]))
    assert pos[0] == pytest.approx([0.0, 0.0, 20.0], abs=1e-6)  # home is the terrain origin
    # east/north in the exact terrain frame vs the DSP's equirectangular metres: 0.3 % apart at most
    assert pos[2, :2] == pytest.approx([2.0 * 0.2, 4.0 * 0.2], rel=4e-3)
    assert vel[1] == pytest.approx([2.0, 4.0, 0.5], abs=1e-3)
    # between two states: linear
    mid, _, _ = world.flight.state(np.array([0.05]))
    a, _, _ = world.flight.state(np.array([0.04]))
    b, _, _ = world.flight.state(np.array([0.06]))
    assert mid[0] == pytest.approx((a[0] + b[0]) / 2, abs=1e-9)
    # the MTi-G's report: LLA of the truth, Euler in its NWU convention = (roll, -pitch, -heading)
    world.gps_fix_at = world.xkf_valid_at = 0.0
    pose = world.true_pose(0.1)
    t = truth(0.1)
    assert pose.valid == 1
    assert pose.lla[:2] == pytest.approx((t.lat, t.lon), abs=1e-9)
    assert pose.lla[2] == pytest.approx(t.alt, abs=1e-6)  # the ECEF round trip is sub-micrometre
    assert pose.euler == pytest.approx((3.0, 4.0, -30.0), abs=1e-6)
    assert pose.vel == pytest.approx((4.0, -2.0, 0.5), abs=1e-3)  # north, west, up
    # the scanner looks where the body points: straight down through the default mounting, rolled right 3°
    _, dirs = world.beam_geometry(np.array([0.1]), np.array([[1.0, 0.0, 0.0]]))
    down = rot[1] @ np.array([0.0, 0.0, -1.0])
    assert dirs[0] == pytest.approx(down, abs=1e-9)


def test_heading_is_interpolated_across_the_wrap() -> None:
    flight = FollowedFlight(HOME)
    flight.add(truth(0.0, heading=179.0))
    flight.add(truth(0.02, heading=-179.0))
    _, _, rot = flight.state(np.array([0.01]))
    level = FollowedFlight(HOME)
    level.add(truth(0.0, heading=-180.0))
    _, _, want = level.state(np.array([0.0]))
    assert rot[0] == pytest.approx(want[0], abs=1e-9)


def test_follow_clock_stands_still_until_the_first_state_then_lags_never_runs_back_nor_past_the_newest() -> None:
    clock = FollowClock(lag=0.25)
    assert clock.now() == 0.0
    time.sleep(0.01)
    assert clock.now() == 0.0, "no DSP yet: time stands still (the MTi-G reports no fix)"
    clock.on_truth(10.0, 4.0)
    t1 = clock.now()
    assert 9.75 <= t1 <= 10.0
    assert clock.wall(4.0) == pytest.approx(1.0)
    clock.on_truth(9.0, 4.0)  # late and old: ignored
    clock.on_truth(10.02, 4.0)
    assert clock.now() >= t1
    clock.on_truth(1000.0, 100.0)
    clock.on_truth(1000.0, 100.0)
    time.sleep(0.05)  # 5 simulated seconds at scale 100: the clock waits at the newest state
    assert clock.now() == 1000.0


def test_dsp_simulator_states_reach_the_receiver_over_udp_and_junk_is_counted() -> None:
    machine = DspMachine()
    clock, flight = FollowClock(), FollowedFlight()
    with TruthReceiver(clock, flight) as rx:
        sender = TruthSender("127.0.0.1", rx.port, time_scale=4.0)
        try:
            for _ in range(20):
                machine.step(0.02)
                sender.send(machine)
            sender._sock.sendto(b"\x93junk", ("127.0.0.1", rx.port))
            wait_until(lambda: rx.received == 20 and rx.invalid == 1, 5.0, "20 states and one junk datagram")
        finally:
            sender.close()
    assert rx.lost == 0 and sender.sent == 20
    assert flight.origin_lla == (machine.params.home_lat, machine.params.home_lon, machine.params.home_alt)
    newest = machine.time_s
    assert newest - clock.lag <= clock.now() <= newest


def test_truth_sender_refuses_a_non_loopback_address() -> None:
    with pytest.raises(ValueError, match="loopback"):
        TruthSender("192.168.0.10", 5000, 1.0)


def test_state_is_read_consistently_while_states_arrive() -> None:
    flight = FollowedFlight(HOME)
    stop = threading.Event()
    errors: list[BaseException] = []

    def feed() -> None:
        k = 0
        while not stop.is_set() and k < 20000:
            flight.add(truth(k * 0.02, seq=k))
            k += 1

    thread = threading.Thread(target=feed)
    thread.start()
    try:
        for _ in range(300):
            pos, _, rot = flight.state(np.linspace(0.0, 50.0, 50))
            if not (np.all(np.isfinite(pos)) and np.allclose(np.linalg.det(rot), 1.0)):
                errors.append(AssertionError("torn read"))
    finally:
        stop.set()
        thread.join()
    assert not errors
    assert flight.samples > 0


def test_dsp_simulator_process_sends_its_truth_and_refuses_a_remote_address() -> None:
    import subprocess
    import sys

    clock, flight = FollowClock(), FollowedFlight()
    with TruthReceiver(clock, flight) as rx:
        proc = subprocess.run([sys.executable, "-m", "modules.dsp.sim", "--tcp", "127.0.0.1:0", "--truth-udp",
                               f"127.0.0.1:{rx.port}", "--time-scale", "4", "--duration", "1.5"],
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        wait_until(lambda: rx.received >= 20, 5.0, "truth datagrams from the simulator process")
    assert rx.invalid == 0 and flight.origin_lla == HOME
    bad = subprocess.run([sys.executable, "-m", "modules.dsp.sim", "--tcp", "127.0.0.1:0", "--truth-udp",
                          "10.1.2.3:5000"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "loopback" in bad.stderr
