"""The simulated DSP flies on the SET_PID groups it is sent: default gains fly well, a bad group flies badly."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bbcs.contracts import dsp as p
from modules.dsp import codec
from modules.dsp.framing import Frame
from modules.dsp.sim.machine import DspMachine
from modules.dsp.sim.vehicle import default_pids

DT = 0.02


class Rig:
    def __init__(self) -> None:
        self.m = DspMachine()
        self.seq = 0

    def send(self, cmd: p.Command) -> None:
        self.seq += 1
        assert self.m.handle(Frame(int(cmd.MSG_ID), self.seq, codec.encode_payload(cmd)), self.m.time_s).ack.status == 0

    def run(self, seconds: float) -> list[tuple[float, np.ndarray]]:
        out = []
        for _ in range(round(seconds / DT)):
            self.m.step(DT)
            st = self.m.vehicle.state
            out.append((st.roll, st.pos.copy()))
        return out


def roll_group(kp_scale: float) -> p.SetPid:
    g = default_pids()[p.Axis.ROLL]
    return p.SetPid(axis=p.Axis.ROLL, kp=g.kp * kp_scale, ki=g.ki, kd=g.kd, integral=g.integral, awu_max=g.awu_max,
                    awu_min=g.awu_min, reference=g.reference, offset=g.offset, sat_high=g.sat_high,
                    sat_low=g.sat_low)


def sidestep(kp_scale: float) -> tuple[float, float]:
    """Take off, load the ROLL group, fly 35 m east (a roll manoeuvre): roll-rate RMS and final miss distance."""
    rig = Rig()
    rig.send(p.SetHelicopterType(heli_type=p.HeliType.H3_CCPM_120))
    rig.send(roll_group(kp_scale))  # as the start-up sequence sends it
    assert rig.m.vehicle.gains[p.Axis.ROLL].kp == pytest.approx(default_pids()[p.Axis.ROLL].kp * kp_scale, rel=1e-6)
    rig.send(p.SetMode(mode=p.Mode.TAKE_OFF))
    rig.run(16)
    rig.send(p.SetMode(mode=p.Mode.PATH_GIVEN_HEADING))  # heading stays north: going east is all roll
    rig.send(p.SetTracking(enable=True))
    rig.send(p.SetSpeed(speed=5.0))
    home = rig.m.params
    target = (home.home_lat, home.home_lon + 4e-4, home.home_alt + 10.0)  # on the DSP's 1e-4° grid: ≈ 35 m east
    rig.send(p.AddWaypoint(lat=target[0], lon=target[1], alt=target[2]))
    flight = rig.run(14)
    rolls = np.array([r for r, _ in flight])
    roll_rate_rms = float(np.sqrt(np.mean((np.diff(rolls) / DT) ** 2)))
    goal = rig.m.to_local(*target)
    miss = float(math.hypot(*(flight[-1][1][:2] - goal[:2])))
    return roll_rate_rms, miss


def test_default_gains_fly_well_and_roll_kp_times_ten_flies_badly() -> None:
    good_rate, good_miss = sidestep(1.0)
    bad_rate, bad_miss = sidestep(10.0)
    assert good_miss < 2.0  # the default gains arrive
    assert good_rate < 15.0  # deg/s RMS: a smooth sidestep
    assert bad_rate > 3.0 * good_rate  # a roll loop ten times too stiff oscillates (limit cycle on the cyclic)
    assert bad_miss > 2.0 + good_miss  # and it does not settle on the waypoint
