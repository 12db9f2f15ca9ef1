"""GRI state → MAVLink messages, rates, STATUSTEXT, parameters and the signature check, pure."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from bbcs.conf.parser import parse_conf
from bbcs.contracts import gri
from bbcs.contracts.geo import Attitude, VelocityNED
from bbcs.contracts.mri import ModuleStatus
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.contracts.tasks import TaskInfo
from cromat.mavlink import statustext, telemetry
from cromat.mavlink.dialect import Encoder, Parser, Signing, mav
from cromat.mavlink.params import conf_params

ROOT = Path(__file__).resolve().parents[3]


def state(**kw: object) -> gri.GriState:
    tel = RobotTelemetry(stamp=1.0, position=GeoPoint(lat=37.4117, lon=-6.0025, alt=32.0),
                         attitude=Attitude(roll=1.0, pitch=-2.0, yaw=270.0),
                         velocity=VelocityNED(vn=3.0, ve=4.0, vd=-1.0), heading_deg=270.0, airborne=True,
                         battery_v=22.5, pan_deg=40.0, tilt_deg=-30.0)
    base: dict[str, object] = dict(
        robot="uav1", kind="uav", stamp=1.0, telemetry=tel, manager_up=True,
        home=GeoPoint(lat=37.4117, lon=-6.0025, alt=12.0), available={"pan_tilt": "pan_tilt"},
        modules=[ModuleStatus(name="dsp", state="up"), ModuleStatus(name="telemetry", state="up")])
    base.update(kw)
    return gri.GriState(**base)  # type: ignore[arg-type]


def test_messages_carry_the_gri_state() -> None:
    s = state()
    pos = telemetry.global_position_int(s, 1000)
    assert (pos.lat, pos.lon, pos.alt, pos.relative_alt) == (374117000, -60025000, 32000, 20000)
    assert (pos.vx, pos.vy, pos.vz, pos.hdg) == (300, 400, -100, 27000)
    hud = telemetry.vfr_hud(s)
    assert hud.groundspeed == pytest.approx(5.0) and hud.climb == pytest.approx(1.0) and hud.heading == 270
    att = telemetry.attitude(s, 0)
    assert att.yaw == pytest.approx(-1.5708, abs=1e-4) and att.pitch == pytest.approx(-0.0349, abs=1e-4)
    status = telemetry.sys_status(s, 25.2, 19.8)
    assert status.voltage_battery == 22500 and status.battery_remaining == 50
    assert status.onboard_control_sensors_health == status.onboard_control_sensors_present != 0
    failed = telemetry.sys_status(state(modules=[ModuleStatus(name="telemetry", state="failed")]))
    assert failed.onboard_control_sensors_health & mav.MAV_SYS_STATUS_SENSOR_GPS == 0
    assert telemetry.gps_raw_int(state(telemetry=None), 0.0).fix_type == mav.GPS_FIX_TYPE_NO_FIX
    assert telemetry.global_position_int(state(telemetry=None), 0) is None
    assert telemetry.gimbal_attitude(s, 0) is not None and telemetry.home_position(s, 0.0).altitude == 12000


def test_heartbeat_type_and_modes_from_the_running_task() -> None:
    beat = telemetry.heartbeat(state())
    assert beat.type == mav.MAV_TYPE_HELICOPTER and beat.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED
    assert beat.custom_mode == telemetry.custom_mode("HOLD")
    assert telemetry.heartbeat(state(kind="uquad")).type == mav.MAV_TYPE_QUADROTOR
    path = TaskInfo(id=7, name="follow_path", task_type="movement", kind="follow_path")
    assert telemetry.flight_mode(state(tasks=[path])) == "MISSION"
    goto = TaskInfo(id=8, name="goto", task_type="movement", kind="goto")
    assert telemetry.flight_mode(state(tasks=[goto]), rtl_task=8) == "RTL"
    land = TaskInfo(id=9, name="land", task_type="movement", kind="land")
    assert telemetry.landed_state(state(tasks=[land])) == mav.MAV_LANDED_STATE_LANDING
    ground = state(telemetry=RobotTelemetry(stamp=1.0, airborne=False))
    assert telemetry.flight_mode(ground) == "READY" and telemetry.landed_state(ground) == mav.MAV_LANDED_STATE_ON_GROUND
    assert telemetry.heartbeat(state(link="failsafe")).system_status == mav.MAV_STATE_CRITICAL


def test_schedule_keeps_rates_and_obeys_set_message_interval() -> None:
    s = telemetry.Schedule()
    sent = [name for i in range(100) for name in s.due(i * 0.01)]  # one second of 100 Hz turns
    assert sent.count("ATTITUDE") == 10 and sent.count("HEARTBEAT") == 1 and sent.count("GLOBAL_POSITION_INT") == 5
    assert s.set_interval("ATTITUDE", -1) and s.set_interval("GLOBAL_POSITION_INT", 50_000)
    sent = [name for i in range(100, 200) for name in s.due(i * 0.01)]
    assert "ATTITUDE" not in sent and sent.count("GLOBAL_POSITION_INT") == 20
    assert not s.set_interval("NOT_A_MESSAGE", 0)


def test_statustext_for_refusals_with_severity_and_chunks() -> None:
    ev = gri.GriEvent(robot="uav1", stamp=1.0, kind="task_failed", task_id=3, task_type="movement",
                      detail="no progress for 30 s")
    text = statustext.event_text(ev)
    assert text.severity == mav.MAV_SEVERITY_ERROR
    assert text.text == "uav1: task_failed movement #3: no progress for 30 s"
    assert statustext.event_text(ev.__class__(robot="uav1", stamp=1.0, kind="failsafe")).severity == \
        mav.MAV_SEVERITY_CRITICAL
    parts = statustext.chunks("x" * 120, 9)
    assert [(len(p), i, n) for p, i, n in parts] == [(50, 9, 0), (50, 9, 1), (20, 9, 2)]
    assert statustext.chunks("x" * 100, 9)[-1] == (b"", 9, 2)  # a full last chunk is followed by an empty one
    seen: set = set()
    err = gri.ErrorRecord(module="dsp", code=12, stamp=5.0, name="NACK", detail="bad frame")
    assert statustext.new_errors(seen, [err]) == [err] and statustext.new_errors(seen, [err]) == []


def test_conf_values_are_parameters() -> None:
    doc = parse_conf("MAX_SPEED: 8.0\nPORT: /dev/ttyUSB0\nGEOFENCE: [37.4, -6.0, 3000]\n"
                     "PID: LONGITUDINAL\n{\n  Kp=1.2  sat_encima=15\n}\n", "x.conf")
    table = conf_params(doc)
    names = [p.name for p in table.params]
    assert names[:4] == ["MAX_SPEED", "GEOFENCE_1", "GEOFENCE_2", "GEOFENCE_3"]
    assert names[4] == "LONGITUDINAL_KP" and len(names[5]) == 16 and names[5].startswith("LONGITUDINA")
    assert table.skipped == ["x.conf:2 PORT"]
    assert "cannot change at run time" in table.refusal("MAX_SPEED") and "no such" in table.refusal("NOPE")
    shipped = conf_params(parse_conf((ROOT / "bbcs_conf" / "uav1.conf").read_text(), "uav1.conf"))
    assert len({p.name for p in shipped.params}) == len(shipped.params) and all(len(p.name) <= 16
                                                                                for p in shipped.params)


def test_signature_check_refuses_forged_replayed_and_unsigned_frames() -> None:
    key = os.urandom(32)
    frames: list[bytes] = []
    sender = Encoder(7, frames.append, Signing(key), compid=190)  # pymavlink signs; the parser is under test
    for pan in (10.0, 20.0):
        sender.send(mav.MAVLink_command_long_message(1, 1, 205, 0, 0, 0, pan, 0, 0, 0, 0))
    forged: list[bytes] = []
    far_future = Signing(os.urandom(32))
    far_future.timestamp += 10**12  # on the same stream (7/190): must not make later genuine frames look replayed
    Encoder(7, forged.append, far_future, compid=190).send(
        mav.MAVLink_command_long_message(1, 1, 205, 0, 0, 0, 30.0, 0, 0, 0, 0))
    plain: list[bytes] = []
    Encoder(7, plain.append, None, compid=192).send(
        mav.MAVLink_command_long_message(1, 1, 205, 0, 0, 0, 40, 0, 0, 0, 0))
    refused: list[str] = []
    shared = Signing(key, refused=refused.append)
    a, b = Parser(shared), Parser(shared)
    assert [m.param3 for m in a.feed(frames[0] + frames[1])] == [10.0, 20.0]
    assert b.feed(frames[0]) == []  # a replay from another link: the signing state is shared
    assert a.feed(forged[0]) == [] and a.feed(plain[0]) == []
    assert [r.split(" from")[0].split(" (")[0] for r in refused] == ["replayed frame", "bad signature",
                                                                      "unsigned frame"]
    # a forged frame with a far-future timestamp does not poison the stream: the next genuine frame is accepted
    sender.send(mav.MAVLink_command_long_message(1, 1, 205, 0, 0, 0, 50.0, 0, 0, 0, 0))
    assert [m.param3 for m in a.feed(frames[-1])] == [50.0]
    assert Parser(None).feed(plain[0])[0].param3 == 40.0  # without a key, unsigned frames are read
