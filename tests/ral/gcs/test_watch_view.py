"""The watch view: 80 columns, every field a pilot needs, errors by name, events kept, several robots."""

from __future__ import annotations

from bbcs.contracts import gri
from bbcs.contracts.error_codes import error_name
from bbcs.contracts.geo import Attitude, GeoPoint, VelocityNED
from bbcs.contracts.robot import RobotTelemetry
from ral.gcs.watch_view import WatchScreen, render

NOW = 1_800_000_000.0


def state(robot: str, **kw) -> gri.GriState:
    tel = dict(stamp=NOW - 0.5, position=GeoPoint(lat=37.4117, lon=-6.0025, alt=22.5),
               attitude=Attitude(roll=1.0, pitch=2.0, yaw=93.0), velocity=VelocityNED(vn=3.0, ve=4.0, vd=-1.0),
               heading_deg=93.0, mode=4, mode_name="TAKE_OFF", airborne=True, waypoints_queued=0, pan_deg=12.0,
               tilt_deg=-30.0, battery_v=24.87)
    tel.update({k: kw.pop(k) for k in list(kw) if k in RobotTelemetry.__struct_fields__})
    base = dict(robot=robot, kind="uav", stamp=NOW - 0.5, telemetry=RobotTelemetry(**tel), link="up", manager_up=True,
                tasks=[gri.TaskInfo(id=3, kind="take_off", name="take_off", task_type="movement", status="running",
                                    started=NOW - 5)],
                modules=[gri.ModuleHealth(name=n, state="up") for n in ("dsp", "telemetry", "pan_tilt", "ral")])
    base.update(kw)
    return gri.GriState(**base)


def test_one_robot_shows_every_field_within_80_columns():
    errors = [gri.ErrorRecord(module="pan_tilt", code=102, stamp=NOW - 2, detail="ref_pan 500"),
              gri.ErrorRecord(module="path_follower", code=1002, stamp=NOW - 1),
              gri.ErrorRecord(module="dsp", code=7, name="LOW_BATTERY", stamp=NOW - 0.5)]
    lines = render({"uav1": state("uav1", errors=errors)}, vision={"uav1": {"state": "found", "confidence": 0.9}},
                   error_name=error_name, now=NOW)
    text = "\n".join(lines)
    assert all(len(line) <= 80 for line in lines), [len(line) for line in lines]
    assert lines[0].startswith("uav1 [uav] TAKE_OFF  airborne  link up  manager up  wp 0  0.5s ago")
    assert "pos 37.411700 -6.002500 alt 22.5 m  hdg 93°  spd 5.0 m/s  vz +1.0" in text
    assert "pan +12.0°  tilt -30.0°  battery 24.9 V  vision found 0.90" in text
    assert "tasks movement:take_off#3 running" in text and "modules 4 up" in text
    assert "pan_tilt 102 REF_PAN_OUT_OF_RANGE: ref_pan 500" in text
    assert "path_follower 1002 DSP_WRONG_MODE" in text
    assert "dsp 7 LOW_BATTERY" in text  # the name the reporter sent wins
    assert lines[-1] == "events: none yet"


def test_events_are_kept_and_several_robots_are_shown():
    clock = [NOW]
    screen = WatchScreen(error_name=error_name, clock=lambda: clock[0])
    screen.state(state("uav2", modules=[gri.ModuleHealth(name="dsp", state="restarting", restarts=2),
                                        gri.ModuleHealth(name="ral", state="up", restarts=1)]))
    screen.state(state("uav1", position=None, velocity=None, heading_deg=None, attitude=None))
    for i in range(12):
        screen.event(gri.GriEvent(robot="uav1", stamp=NOW + i, kind="task_accepted", task_id=i, task_type="movement",
                                  detail=f"take_off {'x' * 90}"))
    screen.state(state("uav2", mode_name="AUTOMATIC"))  # a new state does not wipe the events
    lines = screen.lines()
    assert all(len(line) <= 80 for line in lines)
    heads = [line for line in lines if not line.startswith(" ") and "[uav]" in line]
    assert [h.split()[0] for h in heads] == ["uav1", "uav2"] and "AUTOMATIC" in heads[1]
    assert "pos unknown  hdg -  spd - m/s  vz -" in "\n".join(lines)
    assert "events (last 8):" in lines
    shown = [line for line in lines if "task_accepted" in line]
    assert len(shown) == 8 and "movement#11" in shown[-1] and "movement#4" in shown[0]
    assert shown[-1].endswith("…")


def test_modules_not_up_are_named():
    lines = render({"uav2": state("uav2", modules=[gri.ModuleHealth(name="dsp", state="restarting", restarts=2),
                                                   gri.ModuleHealth(name="ral", state="up", restarts=1)])}, now=NOW)
    assert "  modules 1/2 up; dsp restarting (2 restarts); restarted ral×1" in lines
