"""A robot's GRI state as the MAVLink messages QGroundControl and MAVSDK read, and how often each is sent.

Flight modes are reported in PX4's custom-mode encoding (``main << 16 | sub << 24``), which QGroundControl and
MAVSDK decode for any autopilot, from the running movement task (docs/mavlink.md has the table). ``armed`` is
"airborne": the GRI has no separate arming (take-off starts the engine or motors, landing stops them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from bbcs.contracts import gri
from bbcs.contracts.tasks import MOVEMENT_KINDS
from cromat.mavlink.dialect import Message, mav

UINT16_MAX = 65535

VEHICLE_TYPES: dict[str, int] = {
    "uav": mav.MAV_TYPE_HELICOPTER,  # the CROMAT UAV is an autonomous helicopter (docs/dsp_protocol.md)
    "uquad": mav.MAV_TYPE_QUADROTOR,
}
"""Robot kind → HEARTBEAT type; any other kind is MAV_TYPE_GENERIC."""

PX4_MODES: dict[str, tuple[int, int]] = {
    "MANUAL": (1, 0), "ALTCTL": (2, 0), "POSCTL": (3, 0), "READY": (4, 1), "TAKEOFF": (4, 2), "HOLD": (4, 3),
    "MISSION": (4, 4), "RTL": (4, 5), "LAND": (4, 6), "FOLLOW_TARGET": (4, 8), "PRECLAND": (4, 9),
    "ACRO": (5, 0), "OFFBOARD": (6, 0), "STABILIZED": (7, 0),
}
MODE_OF_KIND: dict[str, str] = {
    "take_off": "TAKEOFF", "land": "LAND", "hold": "HOLD", "goto": "HOLD", "follow_path": "MISSION",
    "survey": "MISSION", "orbit": "MISSION", "manual": "POSCTL", "bridge": "OFFBOARD", "follow_vision_path": "OFFBOARD",
}
"""The running movement task's kind → the PX4 mode it is shown as (a goto is PX4's reposition, flown in HOLD)."""


def custom_mode(name: str) -> int:
    main, sub = PX4_MODES[name]
    return (main << 16) | (sub << 24)


def mode_name(main: int, sub: int) -> str | None:
    for name, (m, s) in PX4_MODES.items():
        if m == main and (s == sub or (s == 0 and sub == 0)):
            return name
    return None


def movement_task(state: gri.GriState) -> gri.TaskInfo | None:
    return next((t for t in state.tasks if t.kind in MOVEMENT_KINDS and t.status == "running"), None)


def flight_mode(state: gri.GriState, rtl_task: int = 0) -> str:
    task = movement_task(state)
    if task is None:
        return "HOLD" if state.airborne else "READY"
    if rtl_task and task.id == rtl_task:
        return "RTL"
    return MODE_OF_KIND.get(task.kind, "HOLD")


def landed_state(state: gri.GriState) -> int:
    if state.airborne is None:
        return mav.MAV_LANDED_STATE_UNDEFINED
    task = movement_task(state)
    kind = task.kind if task else ""
    if not state.airborne:
        return mav.MAV_LANDED_STATE_TAKEOFF if kind == "take_off" else mav.MAV_LANDED_STATE_ON_GROUND
    return mav.MAV_LANDED_STATE_LANDING if kind == "land" else mav.MAV_LANDED_STATE_IN_AIR


def heartbeat(state: gri.GriState, rtl_task: int = 0) -> Message:
    airborne = bool(state.airborne)
    base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if airborne else 0)
    if movement_task(state) is not None:
        base |= mav.MAV_MODE_FLAG_AUTO_ENABLED | mav.MAV_MODE_FLAG_GUIDED_ENABLED
    if state.link == "failsafe" or not state.manager_up:
        status = mav.MAV_STATE_CRITICAL
    elif airborne:
        status = mav.MAV_STATE_ACTIVE
    else:
        status = mav.MAV_STATE_STANDBY
    return mav.MAVLink_heartbeat_message(VEHICLE_TYPES.get(state.kind, mav.MAV_TYPE_GENERIC),
                                         mav.MAV_AUTOPILOT_GENERIC, base, custom_mode(flight_mode(state, rtl_task)),
                                         status, 3)


SENSORS_OF_MODULE: dict[str, int] = {
    "telemetry": mav.MAV_SYS_STATUS_SENSOR_GPS | mav.MAV_SYS_STATUS_AHRS,
    "dsp": mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | mav.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL,
    "path_follower": mav.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL | mav.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL,
    "imu": mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL,
    "gps": mav.MAV_SYS_STATUS_SENSOR_GPS,
    "estimator": mav.MAV_SYS_STATUS_AHRS,
    "controller": mav.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL | mav.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL,
    "motors": mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS,
}
"""Module name → the SYS_STATUS sensor bits it stands for: present when the robot has the module, healthy while it
is up. Modules not listed here count toward nothing (their failures still come as STATUSTEXT)."""


def sensors(state: gri.GriState) -> tuple[int, int]:
    present = health = 0
    for m in state.modules:
        bits = SENSORS_OF_MODULE.get(m.name, 0)
        present |= bits
        if m.state == "up":
            health |= bits
    for m in state.modules:  # a bit is healthy only if every module standing for it is up
        if m.state != "up":
            health &= ~SENSORS_OF_MODULE.get(m.name, 0)
    return present, health


def battery_percent(volts: float | None, full_v: float | None, empty_v: float | None) -> int:
    if volts is None or full_v is None or empty_v is None or full_v <= empty_v:
        return -1
    return max(0, min(100, round(100 * (volts - empty_v) / (full_v - empty_v))))


def sys_status(state: gri.GriState, full_v: float | None = None, empty_v: float | None = None) -> Message:
    present, health = sensors(state)
    volts = state.telemetry.battery_v if state.telemetry else None
    mv = UINT16_MAX if volts is None else min(UINT16_MAX - 1, round(volts * 1000))
    return mav.MAVLink_sys_status_message(present, present, health, 0, mv, -1,
                                          battery_percent(volts, full_v, empty_v), 0, 0, 0, 0, 0, 0)


def _hdg_cdeg(state: gri.GriState) -> int:
    h = state.heading_deg
    if h is None and state.telemetry and state.telemetry.attitude:
        h = state.telemetry.attitude.yaw
    return UINT16_MAX if h is None else round((h % 360.0) * 100) % 36000


def global_position_int(state: gri.GriState, boot_ms: int) -> Message | None:
    p = state.position
    if p is None:
        return None
    v = state.telemetry.velocity if state.telemetry else None
    rel = p.alt - state.home.alt if state.home is not None else 0.0
    return mav.MAVLink_global_position_int_message(
        boot_ms, round(p.lat * 1e7), round(p.lon * 1e7), round(p.alt * 1000), round(rel * 1000),
        round(v.vn * 100) if v else 0, round(v.ve * 100) if v else 0, round(v.vd * 100) if v else 0, _hdg_cdeg(state))


def attitude(state: gri.GriState, boot_ms: int) -> Message | None:
    a = state.telemetry.attitude if state.telemetry else None
    if a is None:
        return None
    yaw = math.radians(((a.yaw + 180.0) % 360.0) - 180.0)
    return mav.MAVLink_attitude_message(boot_ms, math.radians(a.roll), math.radians(a.pitch), yaw, 0.0, 0.0, 0.0)


def vfr_hud(state: gri.GriState) -> Message | None:
    p = state.position
    if p is None:
        return None
    v = state.telemetry.velocity if state.telemetry else None
    ground = math.hypot(v.vn, v.ve) if v else 0.0
    hdg = _hdg_cdeg(state)
    return mav.MAVLink_vfr_hud_message(ground, ground, 0 if hdg == UINT16_MAX else hdg // 100, 0, p.alt,
                                       -v.vd if v else 0.0)


def gps_raw_int(state: gri.GriState, now: float) -> Message:
    p = state.position
    v = state.telemetry.velocity if state.telemetry else None
    if p is None:
        return mav.MAVLink_gps_raw_int_message(int(now * 1e6), mav.GPS_FIX_TYPE_NO_FIX, 0, 0, 0, UINT16_MAX,
                                               UINT16_MAX, UINT16_MAX, UINT16_MAX, 255)
    vel = round(math.hypot(v.vn, v.ve) * 100) if v else UINT16_MAX
    cog = round((math.degrees(math.atan2(v.ve, v.vn)) % 360.0) * 100) % 36000 if v else UINT16_MAX
    # the robot reports a position, not its fix quality: a position is shown as a 3D fix, accuracy unknown
    return mav.MAVLink_gps_raw_int_message(int(now * 1e6), mav.GPS_FIX_TYPE_3D_FIX, round(p.lat * 1e7),
                                           round(p.lon * 1e7), round(p.alt * 1000), UINT16_MAX, UINT16_MAX,
                                           vel, cog, 255)


def home_position(state: gri.GriState, now: float) -> Message | None:
    h = state.home
    if h is None:
        return None
    return mav.MAVLink_home_position_message(round(h.lat * 1e7), round(h.lon * 1e7), round(h.alt * 1000), 0.0, 0.0,
                                             0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(now * 1e6))


def extended_sys_state(state: gri.GriState) -> Message:
    return mav.MAVLink_extended_sys_state_message(mav.MAV_VTOL_STATE_UNDEFINED, landed_state(state))


GIMBAL_DEVICE_ID = 1
"""The pan & tilt is a gimbal the autopilot drives (MAVLink gimbal device ids 1-6: non-MAVLink gimbals)."""


def _quaternion(roll: float, pitch: float, yaw: float) -> list[float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy]


def gimbal_attitude(state: gri.GriState, boot_ms: int) -> Message | None:
    """GIMBAL_DEVICE_ATTITUDE_STATUS from the pan (yaw, relative to the nose) and tilt (pitch) angles."""
    if state.pan_deg is None or state.tilt_deg is None:
        return None
    q = _quaternion(0.0, math.radians(state.tilt_deg), math.radians(state.pan_deg))
    nan = float("nan")
    return mav.MAVLink_gimbal_device_attitude_status_message(
        0, 0, boot_ms, mav.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME, q, nan, nan, nan, 0,
        gimbal_device_id=GIMBAL_DEVICE_ID)


def gimbal_manager_information(boot_ms: int) -> Message:
    caps = (mav.GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_AXIS | mav.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_AXIS
            | mav.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_FOLLOW)
    return mav.MAVLink_gimbal_manager_information_message(boot_ms, caps, GIMBAL_DEVICE_ID, 0.0, 0.0,
                                                          math.radians(-90), math.radians(90),
                                                          math.radians(-180), math.radians(180))


def gimbal_device_information(boot_ms: int) -> Message:
    caps = (mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_AXIS | mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_AXIS
            | mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_FOLLOW)
    return mav.MAVLink_gimbal_device_information_message(
        boot_ms, b"cromat", b"pan_tilt", b"", 0, 0, 0, caps, 0, 0.0, 0.0, math.radians(-90), math.radians(90),
        math.radians(-180), math.radians(180), gimbal_device_id=GIMBAL_DEVICE_ID)


def gimbal_manager_status(boot_ms: int) -> Message:
    return mav.MAVLink_gimbal_manager_status_message(boot_ms, mav.GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME,
                                                     GIMBAL_DEVICE_ID, 0, 0, 0, 0)


def mission_current(seq: int, total: int, state: int) -> Message:
    return mav.MAVLink_mission_current_message(seq, total, state)


# ---------------------------------------------------------------- rates

RATES_HZ: dict[str, float] = {
    "HEARTBEAT": 1.0, "SYS_STATUS": 1.0, "GLOBAL_POSITION_INT": 5.0, "ATTITUDE": 10.0, "VFR_HUD": 4.0,
    "GPS_RAW_INT": 2.0, "HOME_POSITION": 0.2, "EXTENDED_SYS_STATE": 1.0, "MISSION_CURRENT": 1.0,
    "GIMBAL_DEVICE_ATTITUDE_STATUS": 5.0, "GIMBAL_MANAGER_STATUS": 1.0,
}
"""What QGroundControl expects of a vehicle on a telemetry link (PX4's defaults for a normal link, near enough);
SET_MESSAGE_INTERVAL changes them per vehicle. The GRI state itself comes at the RAL's ``state_period_s``."""
MAX_HZ = 50.0


@dataclass
class Schedule:
    """When each message is next due (injected clock)."""

    rates: dict[str, float] = field(default_factory=lambda: dict(RATES_HZ))
    due_at: dict[str, float] = field(default_factory=dict)

    def set_interval(self, name: str, interval_us: float) -> bool:
        """SET_MESSAGE_INTERVAL: -1 stops the message, 0 restores its default; False for a message not sent."""
        if name not in RATES_HZ:
            return False
        if interval_us < 0:
            self.rates[name] = 0.0
        elif interval_us == 0:
            self.rates[name] = RATES_HZ[name]
        else:
            self.rates[name] = min(MAX_HZ, 1e6 / interval_us)
        self.due_at.pop(name, None)
        return True

    def due(self, now: float) -> list[str]:
        out = []
        for name, hz in self.rates.items():
            if hz <= 0:
                continue
            at = self.due_at.get(name)
            if at is None or now >= at:
                out.append(name)
                period = 1.0 / hz
                # keep the cadence, but never send a backlog after a stall
                self.due_at[name] = now + period if at is None or now - at > period else at + period
        return out

    def next_due(self) -> float | None:
        live = [self.due_at.get(n, 0.0) for n, hz in self.rates.items() if hz > 0]
        return min(live) if live else None
