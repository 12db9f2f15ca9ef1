"""Mode 3, the onboard follower: flies a trajectory through the simulated DSP's bridge mode, honours HEADING
and VELOCIDAD, stops on abort, reports its own errors; its gains are the DARE's."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from bbcs.contracts import dsp as p
from bbcs.contracts.error_codes import FollowerError
from bbcs.contracts.path_follower import ControlModoSegCam, DatoPuntoSegCam, DatosSegCam
from control.linearize import discretize
from modules.dsp import codec
from modules.dsp.framing import Frame
from modules.dsp.sim.machine import DspMachine
from modules.path_follower import logic
from modules.path_follower.logic import FollowerState
from modules.path_follower.onboard import OnboardFollower, OnboardParams, decide

DT = 0.02
CELL = 1e-4


class Rig:
    """An airborne simulated DSP in mode 3 and the follower, talking through encoded frames."""

    def __init__(self) -> None:
        self.m = DspMachine()
        self.seq = 0
        self.sent: list[p.Command] = []
        for cmd in (p.SetTelemetryMask(mask=0x7FF), p.SetHelicopterType(heli_type=p.HeliType.H3_CCPM_120),
                    p.SetMode(mode=p.Mode.TAKE_OFF)):
            self.send(cmd)
        self.run(16)
        self.send(p.SetMode(mode=p.Mode.ONBOARD_FOLLOWER))

    def send(self, cmd: p.Command) -> None:
        self.seq += 1
        assert self.m.handle(Frame(int(cmd.MSG_ID), self.seq, codec.encode_payload(cmd)), self.m.time_s).ack.status == 0

    def telemetry(self) -> p.Telemetry:
        return codec.decode(Frame(int(p.MsgId.TELEMETRY), 0, codec.encode_payload(self.m.telemetry())))

    def run(self, seconds: float, follower: OnboardFollower | None = None) -> list[np.ndarray]:
        track = []
        for k in range(round(seconds / DT)):
            if follower is not None and k % 3 == 0:  # 60 ms control period
                for cmd in follower.step(self.m.time_s, self.telemetry()).commands:
                    self.sent.append(cmd)
                    self.send(cmd)
            self.m.step(DT)
            track.append(self.m.vehicle.state.pos.copy())
        return track

    def grid(self, north_cells: int, east_cells: int, up: float) -> tuple[float, float, float]:
        par = self.m.params
        return (par.home_lat + north_cells * CELL, par.home_lon + east_cells * CELL, par.home_alt + 10.0 + up)


def test_flies_an_l_shaped_trajectory_with_a_climb_through_bridge_references() -> None:
    rig = Rig()
    f = OnboardFollower(OnboardParams(period_s=0.06))
    f.set_speed(5.0)
    pts = [rig.grid(4, 0, 0.0), rig.grid(4, 5, 4.0)]  # ≈ 45 m north, then ≈ 44 m east climbing 4 m
    f.set_points(pts)
    track = rig.run(40, f)
    assert f.complete
    assert {type(c) for c in rig.sent} == {p.SetRefs}  # only bridge references reach the DSP
    msgspec.msgpack.encode(rig.sent)  # and they cross the bus as they are (plain floats, no numpy scalars)
    local = [rig.m.to_local(*pt) for pt in pts]
    end = local[-1]
    assert np.linalg.norm(track[-1] - end) < 1.5
    first_leg = [x for x in track if x[0] < local[0][0] - 3]
    assert max(abs(x[1]) for x in first_leg) < 1.5  # cross-track on the first leg (east deviation)
    assert max(x[2] for x in track) < end[2] + 1.0  # climbs to the last point's height without overshooting


def test_at_the_end_one_reference_holds_the_end_point_and_nothing_more_is_sent() -> None:
    """Campaign seed 7, sequence 111: after a mode-3 follow_path completed, the follower kept sending SET_REFS
    (holding the end itself) while no task ran. Now the last reference is the end point, the DSP's bridge law
    flies there and holds it, and the trajectory is forgotten: 20 s later nothing more has been sent."""
    rig = Rig()
    f = OnboardFollower(OnboardParams(period_s=0.06))
    f.set_speed(5.0)
    end = rig.grid(3, 2, 2.0)
    state = FollowerState(mode=3, path=(DatoPuntoSegCam(latitud=rig.grid(3, 0, 0)[0], longitud=rig.grid(3, 0, 0)[1],
                                                       altura=rig.grid(3, 0, 0)[2]),
                                        DatoPuntoSegCam(latitud=end[0], longitud=end[1], altura=end[2])))
    sent_at: list[float] = []
    last_detail = ""
    for k in range(round(60 / DT)):
        if k % 3 == 0:
            d = decide(f, state, rig.telemetry())
            state = d.state
            for cmd in d.commands:
                sent_at.append(rig.m.time_s)
                rig.sent.append(cmd)
                rig.send(cmd)
            last_detail = d.detail or last_detail
        rig.m.step(DT)
    assert {type(c) for c in rig.sent} == {p.SetRefs}
    assert state.path == () and not f.points and "complete" in last_detail
    assert sent_at[-1] < 40.0  # the last reference, then 20 s and more of nothing
    here = rig.m.vehicle.state.pos
    assert np.linalg.norm(here - rig.m.to_local(*end)) < 0.5  # held at the end point
    assert np.linalg.norm(rig.m.vehicle.state.vel) < 0.05


def test_heading_and_speed_are_honoured() -> None:
    rig = Rig()
    f = OnboardFollower(OnboardParams(period_s=0.06))
    f.set_points([rig.grid(10, 0, 0.0)])
    rig.run(3, f)
    assert np.hypot(*rig.m.vehicle.state.pos[:2]) < 0.5  # VELOCIDAD 0 (never set): no progress
    f.set_speed(4.0)
    refs = f.step(rig.m.time_s, rig.telemetry()).commands[0]
    assert refs.ref_heading == pytest.approx(0.0, abs=1e-6)  # no HEADING: face along the path (north)
    f.set_heading(-math.pi / 2)
    rig.run(8, f)
    st = rig.m.vehicle.state
    assert st.heading == pytest.approx(-90.0, abs=2.0) and st.vel[0] > 3.0  # flying north looking west


def test_abort_empties_the_trajectory_and_nothing_more_is_sent() -> None:
    rig = Rig()
    f = OnboardFollower(OnboardParams(period_s=0.06))
    f.set_speed(5.0)
    pt = DatoPuntoSegCam(latitud=rig.grid(10, 0, 0)[0], longitud=rig.grid(10, 0, 0)[1], altura=rig.grid(10, 0, 0)[2])
    state = FollowerState(mode=3, path=(pt,))
    assert decide(f, state, rig.telemetry()).commands  # flying
    aborted = logic.on_control_modo(state, ControlModoSegCam(modo_o_comando=1, numero_de_comando=0))
    assert aborted.commands == (p.Abort(),) and aborted.state.path == ()
    assert decide(f, aborted.state, rig.telemetry()).commands == () and not f.points


def test_own_errors_no_navigation_once_and_off_path_aborts() -> None:
    f = OnboardFollower()
    f.set_speed(3.0)
    f.set_points([(37.5, -6.0, 30.0)])
    bare = p.Telemetry(time_ms=0, heading=0.0)
    assert f.step(0.0, bare).errors == (FollowerError.NO_NAVIGATION,)
    assert f.step(0.05, bare) == f.step(0.1, bare)  # reported once, nothing sent
    far = p.Telemetry(time_ms=100, heading=0.0, position=p.TelPosition(lat=37.4, lon=-6.0, alt=30.0),
                      velocity=p.TelVelocity(vn=0.0, ve=0.0, vd=0.0))
    pt = DatoPuntoSegCam(latitud=37.5, longitud=-6.0, altura=30.0)
    f2 = OnboardFollower()
    d = decide(f2, FollowerState(mode=3, path=(pt,)), far)
    assert d.commands and isinstance(d.commands[0], p.SetRefs)  # 11 km away but on the (first) segment's line
    off = p.Telemetry(time_ms=200, heading=0.0, position=p.TelPosition(lat=37.45, lon=-5.99, alt=30.0),
                      velocity=p.TelVelocity(vn=0.0, ve=0.0, vd=0.0))
    d = decide(f2, d.state, off)  # ≈ 880 m east of that line
    assert d.errors == (FollowerError.OFF_PATH,) and d.commands == (p.Abort(),) and d.state.path == ()


def test_a_second_datos_extends_the_trajectory_also_before_the_first_fix() -> None:
    f = OnboardFollower()
    f.set_speed(3.0)
    a, b = (37.001, -6.0, 30.0), (37.001, -5.999, 30.0)
    f.set_points([a])
    f.set_points([a, b])  # no telemetry yet: nothing to build the segments from, nothing fails
    fix = p.Telemetry(time_ms=0, heading=0.0, position=p.TelPosition(lat=37.0, lon=-6.0, alt=30.0),
                      velocity=p.TelVelocity(vn=0.0, ve=0.0, vd=0.0))
    assert f.step(0.0, fix).commands and len(f.segments) == 2
    f.set_points([a, b, a])  # extends: one more segment, the flown ones kept
    assert len(f.segments) == 3
    f.set_points([b])  # a different trajectory replaces it
    assert f.points == (b,) and f.segments == []


def test_segment_gains_solve_the_discrete_riccati_equation() -> None:
    f = OnboardFollower(OnboardParams(period_s=0.05))
    f.set_speed(5.0)
    f.set_points([(37.0009, -6.0, 10.0), (37.0009, -5.999, 20.0)])
    f.step(0.0, p.Telemetry(time_ms=0, heading=0.0, position=p.TelPosition(lat=37.0, lon=-6.0, alt=10.0),
                            velocity=p.TelVelocity(vn=0.0, ve=0.0, vd=0.0)))
    tau_h, tau_v = f.guided.tau_h, f.guided.tau_v
    par = f.params
    for seg in f.segments:
        proj = np.vstack([seg.normal, seg.binormal])
        a_vv = proj @ np.diag([-1 / tau_h, -1 / tau_h, -1 / tau_v]) @ proj.T  # hand-written model, not casadi
        b_v = proj @ np.diag([1 / tau_h, 1 / tau_h, 1 / tau_v]) @ proj.T
        az = np.block([[np.zeros((2, 2)), np.eye(2)], [np.zeros((2, 2)), a_vv]])
        bz = np.vstack([np.zeros((2, 2)), b_v])
        ad, bd = discretize(az, bz, 0.05)
        q = np.diag([par.q_pos, par.q_pos, par.q_vel, par.q_vel])
        r = np.eye(2) * par.r
        pr = solve_discrete_are(ad, bd, q, r)
        k = np.linalg.solve(r + bd.T @ pr @ bd, bd.T @ pr @ ad)
        assert seg.gain == pytest.approx(k, rel=1e-6, abs=1e-9)


def test_mode_3_in_the_decision_logic() -> None:
    pt = DatoPuntoSegCam(latitud=37.5, longitud=-6.0, altura=30.0)
    d = logic.on_control_modo(FollowerState(mode=0, path=(pt,)), ControlModoSegCam(modo_o_comando=0,
                                                                                    modo_de_funcionamiento=3))
    assert d.commands == (p.SetMode(mode=p.Mode.ONBOARD_FOLLOWER), p.InvalidatePath()) and d.errors == ()
    assert d.state.mode == 3 and d.state.path == ()
    d = logic.on_datos(d.state, DatosSegCam(n_points=1, puntos=[pt]))
    assert d.commands == () and d.state.path == (pt,)  # kept onboard, no ADD_WAYPOINT
    d = logic.on_datos(d.state, DatosSegCam(n_points=1, puntos=[pt]))
    assert d.state.path == (pt, pt)  # a second DATOS appends, as the DSP queue would
