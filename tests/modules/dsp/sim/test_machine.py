"""The simulated DSP's state machine and flight, driven directly with an injected time step (no I/O)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bbcs.contracts import dsp as p
from bbcs.geodesy import offset
from modules.dsp import codec
from modules.dsp.framing import Frame
from modules.dsp.sim.machine import DspMachine, DspParams
from modules.dsp.sim.vehicle import VehicleParams

E = p.ErrorCode
DT = 0.02


class Driver:
    """Sends commands to a DspMachine as framed bytes would arrive, with a fake link clock."""

    def __init__(self, machine: DspMachine | None = None) -> None:
        self.m = machine or DspMachine()
        self.seq = 0
        self.link_time = 0.0

    def send(self, cmd: p.Command) -> int:
        self.seq = (self.seq + 1) & 0xFF
        self.link_time += 0.01
        frame = Frame(int(cmd.MSG_ID), self.seq, codec.encode_payload(cmd))
        result = self.m.handle(frame, self.link_time)
        assert result.ack.acked_id == cmd.MSG_ID and result.ack.acked_seq == self.seq
        return result.ack.status

    def run(self, seconds: float) -> list[p.Message]:
        out: list[p.Message] = []
        for _ in range(round(seconds / DT)):
            out += self.m.step(DT)
        return out

    def configure(self) -> None:
        assert self.send(p.SetHelicopterType(heli_type=p.HeliType.H3_CCPM_120)) == 0

    def take_off(self) -> None:
        self.configure()
        assert self.send(p.SetMode(mode=p.Mode.TAKE_OFF)) == 0
        self.run(20)
        assert self.m.vehicle.state.pos[2] == pytest.approx(10.0, abs=0.3)

    def follow_paths(self, speed: float | None = None) -> None:
        """Airborne in mode 0 with tracking on (and ``speed`` commanded): what a waypoint test starts from."""
        self.take_off()
        self.send(p.SetMode(mode=p.Mode.PATH_AUTO_HEADING))
        self.send(p.SetTracking(enable=True))
        if speed is not None:
            self.send(p.SetSpeed(speed=speed))

    def waypoint(self, north: float, east: float, up: float) -> p.AddWaypoint:
        par = self.m.params
        lat, lon = offset(par.home_lat, par.home_lon, north, east)
        return p.AddWaypoint(lat=round(lat, 4), lon=round(lon, 4), alt=par.home_alt + up)


def test_initial_state_is_safe() -> None:
    m = DspMachine()
    assert m.mode == p.Mode.SEMI_AUTOMATIC and not m.tracking and not m.path_valid and not m.queue
    assert m.speed_cmd == 0.0 and not m.state_tx and m.error_code == 0
    assert m.step(DT) == []  # nothing is sent before state transmission is enabled


def test_flight_modes_need_the_helicopter_type() -> None:
    d = Driver()
    for mode in (0, 1, 3, 4, 5, 6):
        assert d.send(p.SetMode(mode=p.Mode(mode))) == E.NOT_CONFIGURED
    assert d.m.error_code == E.NOT_CONFIGURED
    assert d.send(p.SetMode(mode=p.Mode.SEMI_AUTOMATIC)) == 0
    d.configure()
    assert d.send(p.SetMode(mode=p.Mode.TAKE_OFF)) == 0
    assert d.send(p.ClearError()) == 0 and d.m.error_code == 0


def test_out_of_range_values_in_a_well_formed_frame_are_refused() -> None:
    d = Driver()
    frame = Frame(int(p.MsgId.SET_MODE), 1, bytes([9]))
    result = d.m.handle(frame, 0.0)
    assert result.ack.status == E.OUT_OF_RANGE and d.m.mode == p.Mode.SEMI_AUTOMATIC
    assert result.command == p.SetMode(mode=9)  # type: ignore[arg-type]
    frame = Frame(int(p.MsgId.SET_SPEED), 2, b"\x00\x00\xc0\x7f")
    assert d.m.handle(frame, 0.1).ack.status == E.OUT_OF_RANGE  # NaN speed
    assert d.m.speed_cmd == 0.0


def test_retransmission_is_acknowledged_but_not_applied_twice() -> None:
    d = Driver()
    wp = codec.encode_payload(d.waypoint(10, 0, 5))
    frame = Frame(int(p.MsgId.ADD_WAYPOINT), 42, wp)
    first = d.m.handle(frame, 1.0)
    again = d.m.handle(frame, 1.3)
    assert first.ack == again.ack and not first.duplicate and again.duplicate
    assert len(d.m.queue) == 1
    later = d.m.handle(frame, 1.0 + 2.5)  # outside the 2 s window: a new command after all
    assert not later.duplicate and len(d.m.queue) == 2
    other = Frame(int(p.MsgId.ADD_WAYPOINT), 42, codec.encode_payload(d.waypoint(20, 0, 5)))
    assert not d.m.handle(other, 3.6).duplicate  # same seq, different payload: applied


def test_abort_empties_the_queue_and_holds() -> None:
    d = Driver()
    d.follow_paths(8)
    for i in range(5):
        assert d.send(d.waypoint(100 + 50 * i, 0, 10)) == 0
    d.run(5)
    assert d.m.following and d.m.vehicle.state.ground_speed > 3
    assert d.send(p.Abort()) == 0
    assert len(d.m.queue) == 0 and not d.m.path_valid and not d.m.following
    d.run(10)
    st = d.m.vehicle.state
    assert st.ground_speed < 0.1  # stopped: holding where it could stop
    held = st.pos.copy()
    d.run(5)
    assert np.linalg.norm(d.m.vehicle.state.pos - held) < 0.2


def test_invalidate_clears_the_path_and_tracking_off_stops_following() -> None:
    d = Driver()
    d.follow_paths(5)
    d.send(d.waypoint(200, 0, 10))
    d.run(3)
    assert d.m.following
    assert d.send(p.SetTracking(enable=False)) == 0
    assert not d.m.following and len(d.m.queue) == 1 and d.m.path_valid  # path kept, not followed
    d.run(10)
    stopped_at = d.m.vehicle.state.pos[0]
    d.run(5)
    assert d.m.vehicle.state.pos[0] == pytest.approx(stopped_at, abs=0.1)
    d.send(p.SetTracking(enable=True))
    d.run(3)
    assert d.m.vehicle.state.pos[0] > stopped_at + 3  # resumes the same path
    assert d.send(p.InvalidatePath()) == 0
    assert not d.m.path_valid and not d.m.queue and not d.m.following
    d.send(d.waypoint(0, 0, 10))  # a new waypoint makes a new valid path
    assert d.m.path_valid and d.m.following


def test_mode_0_flies_the_waypoints_in_order_facing_each() -> None:
    d = Driver()
    d.follow_paths(6)
    legs = [(60, 0, 10), (60, 60, 15), (0, 60, 15)]
    wps = [d.waypoint(*leg) for leg in legs]
    for wp in wps:
        d.send(wp)
    targets = [d.m.to_local(wp.lat, wp.lon, wp.alt) for wp in wps]
    closest = [math.inf] * 3
    speeds = []
    heading_errors = []
    reached, reached_at = 0, 0.0
    for _ in range(round(90 / DT)):
        d.m.step(DT)
        st = d.m.vehicle.state
        if d.m.waypoints_reached != reached:
            reached, reached_at = d.m.waypoints_reached, d.m.time_s
        speeds.append(st.ground_speed)
        for i, t in enumerate(targets):
            closest[i] = min(closest[i], float(np.linalg.norm(t - st.pos)))
        if d.m.queue:
            to_go = d.m.queue[0].local - st.pos
            if math.hypot(to_go[0], to_go[1]) > 10 and d.m.time_s - reached_at > 3.0:  # turned by now
                bearing = math.degrees(math.atan2(to_go[1], to_go[0]))
                heading_errors.append(abs((st.heading - bearing + 180) % 360 - 180))
    assert max(heading_errors) < 10  # faces the next waypoint whenever it is on its way
    assert d.m.waypoints_reached == 3 and not d.m.queue
    assert max(closest) < 1.9  # arrival radius 1.5 m horizontal, 1.0 m vertical
    assert max(speeds) <= 6.0 + 1e-6  # never faster than commanded
    d.run(5)
    assert np.linalg.norm(d.m.vehicle.state.pos - targets[-1]) < 1.9  # and holds at the last one


def test_speed_is_limited_by_the_airframe_maximum() -> None:
    d = Driver(DspMachine(vehicle_params=VehicleParams(max_speed=4.0)))
    d.follow_paths()
    assert d.send(p.SetSpeed(speed=20)) == 0
    assert d.m.speed_cmd == 4.0
    d.send(d.waypoint(300, 0, 10))
    top = 0.0
    for _ in range(round(30 / DT)):
        d.m.step(DT)
        top = max(top, d.m.vehicle.state.ground_speed)
    assert 3.9 < top <= 4.0 + 1e-6


def test_speed_zero_means_no_progress() -> None:
    d = Driver()
    d.follow_paths()
    d.send(d.waypoint(100, 0, 10))
    d.run(10)
    assert abs(d.m.vehicle.state.pos[0]) < 0.5


def test_mode_1_holds_the_given_heading() -> None:
    d = Driver()
    d.take_off()
    d.send(p.SetMode(mode=p.Mode.PATH_GIVEN_HEADING))
    assert d.send(p.SetHeading(heading_deg=-90.0)) == 0
    d.send(p.SetTracking(enable=True))
    d.send(p.SetSpeed(speed=5))
    d.send(d.waypoint(100, 0, 10))  # flying north while looking west
    d.run(15)
    st = d.m.vehicle.state
    assert st.heading == pytest.approx(-90.0, abs=0.5)
    assert st.vel[0] > 4


def test_take_off_then_landing() -> None:
    d = Driver()
    d.configure()
    assert d.m.vehicle.state.rotor_rpm == 0
    d.send(p.SetMode(mode=p.Mode.TAKE_OFF))
    d.run(2)
    assert d.m.vehicle.state.pos[2] < 1.5  # the rotor spins up before lift-off
    d.run(18)
    st = d.m.vehicle.state
    assert st.airborne and st.pos[2] == pytest.approx(10.0, abs=0.3) and abs(st.vel[2]) < 0.1
    assert np.hypot(st.pos[0], st.pos[1]) < 0.1  # straight up
    d.send(p.SetMode(mode=p.Mode.LANDING))
    descent = []
    for _ in range(round(25 / DT)):
        d.m.step(DT)
        descent.append(-d.m.vehicle.state.vel[2])
    st = d.m.vehicle.state
    assert not st.airborne and st.pos[2] == 0.0
    assert max(descent) <= 0.7 + 1e-6
    d.run(10)
    assert d.m.vehicle.state.rotor_rpm < 50  # idled on the ground


def test_abort_stops_a_take_off() -> None:
    d = Driver()
    d.configure()
    d.send(p.SetMode(mode=p.Mode.TAKE_OFF))
    d.run(6)
    d.send(p.Abort())
    d.run(8)
    alt = d.m.vehicle.state.pos[2]
    d.run(5)
    assert 0 < alt < 9 and d.m.vehicle.state.pos[2] == pytest.approx(alt, abs=0.2)


def test_bridge_mode_follows_refs() -> None:
    d = Driver()
    d.take_off()
    refs = p.SetRefs(ref_altura=d.m.params.home_alt + 20, error_longitudinal=30, error_lateral=-10,
                     ref_heading=math.radians(45), ref_rpm_motor=1400)
    assert d.send(refs) == E.WRONG_MODE  # only in modes 3 and 6
    assert d.send(p.SetMode(mode=p.Mode.BRIDGE)) == 0
    heading0 = d.m.vehicle.state.heading
    assert d.send(refs) == 0
    d.run(30)
    st = d.m.vehicle.state
    psi = math.radians(heading0)
    expect_n = 30 * math.cos(psi) + 10 * math.sin(psi)
    expect_e = 30 * math.sin(psi) - 10 * math.cos(psi)
    assert st.pos[0] == pytest.approx(expect_n, abs=0.5) and st.pos[1] == pytest.approx(expect_e, abs=0.5)
    assert st.pos[2] == pytest.approx(20, abs=0.3)
    assert st.heading == pytest.approx(45, abs=0.5)
    assert st.rotor_rpm == pytest.approx(1400, abs=5)


def test_pan_tilt_modes() -> None:
    d = Driver()
    assert d.send(p.SetPanTiltAngles(pan_deg=30, tilt_deg=-20)) == E.WRONG_MODE  # starts in HOLD
    d.send(p.SetPanTiltMode(mode=p.PanTiltMode.ANGLES))
    assert d.send(p.SetPanTiltAngles(pan_deg=30, tilt_deg=-20)) == 0
    d.run(1)
    assert (d.m.pan, d.m.tilt) == pytest.approx((30, -20))
    assert d.send(p.SetPanTiltTarget(lat=0, lon=0, alt=0)) == E.WRONG_MODE
    d.send(p.SetPanTiltMode(mode=p.PanTiltMode.TARGET))
    # a target about 100 m east, 100 m below the home ground (on the 1e-4 degree grid): pan 90°, tilt ≈ -45°
    target = d.waypoint(0, 100, -100)
    assert d.send(p.SetPanTiltTarget(lat=target.lat, lon=target.lon, alt=target.alt)) == 0
    east = d.m.to_local(target.lat, target.lon, target.alt)[1]
    d.run(3)
    assert d.m.pan == pytest.approx(90, abs=0.5)
    assert d.m.tilt == pytest.approx(-math.degrees(math.atan2(100, east)), abs=0.5)
    d.take_off()  # heading stays north; the camera keeps pointing at the target
    d.run(2)
    assert d.m.tilt == pytest.approx(-math.degrees(math.atan2(110, east)), abs=1.0)
    d.send(p.SetPanTiltMode(mode=p.PanTiltMode.HOLD))
    d.send(p.SetMode(mode=p.Mode.PATH_GIVEN_HEADING))
    d.send(p.SetHeading(heading_deg=60))
    d.run(5)
    assert d.m.vehicle.state.heading == pytest.approx(60, abs=0.5)
    assert d.m.pan == pytest.approx(30, abs=1.0)  # world azimuth 90° kept while the body turned 60°


def test_queue_full() -> None:
    d = Driver(DspMachine(DspParams(queue_capacity=3)))
    for i in range(3):
        assert d.send(d.waypoint(i, 0, 0)) == 0
    assert d.send(d.waypoint(9, 0, 0)) == E.QUEUE_FULL
    assert len(d.m.queue) == 3 and d.m.error_code == E.QUEUE_FULL


def test_telemetry_at_the_configured_period_with_the_mask() -> None:
    d = Driver()
    d.send(p.SetTelemetryMask(mask=int(p.TelemetryField.POSITION | p.TelemetryField.STATUS)))
    d.send(p.SetStateTransmission(enable=True, period_ms=100))
    out = d.run(2.0)
    telemetry = [m for m in out if isinstance(m, p.Telemetry)]
    times = [t.time_ms for t in telemetry]
    assert times[:3] == [20, 100, 200] and times[-1] == 2000  # first at once, then every 100 ms
    assert all(b - a == 100 for a, b in zip(times[1:], times[2:], strict=False))
    assert all(t.mask == 0b100001 and t.status is not None for t in telemetry)
    assert telemetry[0].position == p.TelPosition(lat=d.m.params.home_lat, lon=d.m.params.home_lon,
                                               alt=d.m.params.home_alt)
    d.send(p.SetStateTransmission(enable=False, period_ms=100))
    assert not [m for m in d.run(1.0) if isinstance(m, p.Telemetry)]


def test_errors_are_sent_and_latched() -> None:
    d = Driver(DspMachine(vehicle_params=VehicleParams(battery_full=21.05, battery_drain=0.1)))
    d.m.scheduled_errors = [(0.5, int(E.GPS_LOST))]
    d.send(p.SetTelemetryMask(mask=int(p.TelemetryField.ERROR)))
    out = d.run(1.0)
    errors = [m for m in out if isinstance(m, p.DspError)]
    assert [(e.code, e.time_ms) for e in errors] == [(E.GPS_LOST, 500)]
    assert d.m.telemetry().error_code == E.GPS_LOST
    d.send(p.ClearError())
    assert d.m.telemetry().error_code == 0
    d.take_off()  # the rotor drains the battery below 21 V
    assert any(isinstance(m, p.DspError) and m.code == E.LOW_BATTERY for m in d.m.step(DT)) or \
        d.m.error_code == E.LOW_BATTERY
    d.m.note_rx_errors()
    d.m.note_rx_errors()  # at most once per second
    assert [m.code for m in d.m.step(DT) if isinstance(m, p.DspError)] == [E.RX_ERRORS]
