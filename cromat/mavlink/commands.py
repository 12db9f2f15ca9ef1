"""COMMAND_LONG / COMMAND_INT → what the gateway does: a GRI request, a refusal with its reason, or a local answer.

Pure: :func:`map_command` reads a :class:`Command` and the vehicle's :class:`Context` and returns one outcome; the
gateway sends :class:`Send`'s request to the RAL and answers COMMAND_ACK with the RAL's verdict (DENIED plus a
STATUSTEXT with its reason on a refusal). docs/mavlink.md has the table of what is mapped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from bbcs.contracts import gri
from bbcs.contracts.robot import GeoPoint
from bbcs.geodesy import distance_m
from cromat.mavlink.dialect import mav
from cromat.mavlink.plan import AMSL_FRAMES, Plan, PlanError, command_name, to_altitude_amsl
from cromat.mavlink.telemetry import PX4_MODES, mode_name


@dataclass(frozen=True, slots=True)
class Command:
    command: int
    params: tuple[float, ...]
    """param1..param7 (COMMAND_INT: param5/6 are x/y as degrees, param7 z)."""
    frame: int = mav.MAV_FRAME_GLOBAL
    """COMMAND_LONG positions are in the command's default frame (AMSL); COMMAND_INT says its frame."""

    def p(self, n: int) -> float:
        return self.params[n - 1]


def command_of(msg: object) -> Command:
    """From a COMMAND_LONG or COMMAND_INT message."""
    m = msg
    if m.get_type() == "COMMAND_INT":  # type: ignore[attr-defined]
        params = (m.param1, m.param2, m.param3, m.param4, m.x / 1e7, m.y / 1e7, m.z)  # type: ignore[attr-defined]
        return Command(m.command, tuple(float(v) for v in params), m.frame)  # type: ignore[attr-defined]
    params = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)  # type: ignore[attr-defined]
    return Command(m.command, tuple(float(v) for v in params))  # type: ignore[attr-defined]


Role = Literal["task", "mission", "rtl", "pause", "mission_takeoff"]


@dataclass(frozen=True, slots=True)
class Send:
    """Send ``request`` to the robot's RAL; the COMMAND_ACK is its verdict."""

    request: gri.TaskRequest
    role: Role = "task"
    offset: int = 0
    """For a mission: the index of the plan's first waypoint in this path."""


@dataclass(frozen=True, slots=True)
class Deny:
    reason: str
    result: int = mav.MAV_RESULT_DENIED


@dataclass(frozen=True, slots=True)
class Local:
    """Answered by the gateway itself (ACCEPTED unless it says otherwise)."""

    what: Literal["request_message", "message_interval", "set_current", "speed"]
    args: tuple[float, ...] = ()


Outcome = Send | Deny | Local


@dataclass(frozen=True, slots=True)
class Context:
    robot: str
    kind: str
    available: frozenset[str]
    """The GRI task kinds this robot offers (GriState.available)."""
    home: GeoPoint | None = None
    position: GeoPoint | None = None
    airborne: bool | None = None
    takeoff_height: float | None = None
    """The .conf's TAKEOFF_HEIGHT (or the uQuad's TAKEOFF_HEIGHT_DEFAULT), when the gateway has the .conf."""
    max_speed: float | None = None
    rtl_height: float = 10.0
    """The return to launch's height above home (the .conf's RETURN_HEIGHT; 10 m without it)."""
    plan: Plan | None = None
    mission_index: int = 0
    """Index of the plan's waypoint a mission start begins at (MISSION_SET_CURRENT moves it)."""
    mission_running: bool = False
    paused_at: int | None = None
    """The plan index a paused mission continues from."""
    running_path: tuple[gri.Waypoint, ...] = ()
    """What is left of the running goto/follow_path (for DO_CHANGE_SPEED)."""
    running_role: Role = "task"
    running_offset: int = 0
    speed: float | None = None
    """A speed set while no path ran: the next path flies at it."""
    extra: dict[str, float] = field(default_factory=dict)


def _needs(ctx: Context, kind: str, what: str) -> Deny | None:
    if kind not in ctx.available:
        return Deny(f"{ctx.robot} ({ctx.kind}) cannot {what}: it offers no {kind} task")
    return None


def _finite(v: float) -> bool:
    return not math.isnan(v) and not math.isinf(v)


def _speed(ctx: Context) -> float | None:
    return ctx.speed


def _mission_from(ctx: Context, index: int) -> Outcome:
    plan = ctx.plan
    if plan is None:
        return Deny(f"{ctx.robot}: no mission uploaded to start")
    if not 0 <= index < len(plan.waypoints):
        return Deny(f"{ctx.robot}: the mission has no waypoint at or after that item")
    if (d := _needs(ctx, "follow_path", "fly a mission")) is not None:
        return d
    if plan.takeoff and ctx.airborne is False:  # its NAV_TAKEOFF first; the gateway starts the path once it is done
        if (d := _needs(ctx, "take_off", "take off")) is not None:
            return d
        height = plan.takeoff_height or ctx.takeoff_height or gri.TakeOff().height
        return Send(gri.TakeOff(height=height), "mission_takeoff", index)
    return mission_path(ctx, plan, index)


def mission_path(ctx: Context, plan: Plan, index: int) -> Send:
    """The mission's path from its waypoint ``index`` on, as one follow_path."""
    speed = plan.speed if plan.speed is not None else _speed(ctx)
    return Send(gri.FollowPath(waypoints=list(plan.waypoints[index:]), speed=speed), "mission", index)


def _index_of_seq(plan: Plan | None, seq: int) -> int:
    if plan is None:
        return 0
    for i, s in enumerate(plan.seqs):
        if s >= seq:
            return i
    return len(plan.seqs)


def _takeoff(ctx: Context, cmd: Command) -> Outcome:
    if (d := _needs(ctx, "take_off", "take off")) is not None:
        return d
    amsl = cmd.p(7)
    if _finite(amsl) and ctx.home is not None and amsl > ctx.home.alt:
        height = amsl - ctx.home.alt  # the RAL refuses a height its take-off cannot fly, with the reason
    else:  # PX4's rule: no altitude, or one below the vehicle, means the vehicle's own take-off height
        height = ctx.takeoff_height if ctx.takeoff_height is not None else gri.TakeOff().height
    return Send(gri.TakeOff(height=height))


def rtl(ctx: Context) -> Outcome:
    """Return to launch: the goto home (the gateway lands the robot once it completes)."""
    return _rtl(ctx)


def _rtl(ctx: Context) -> Outcome:
    if (d := _needs(ctx, "goto", "return to launch")) is not None:
        return d
    if ctx.home is None:
        return Deny(f"{ctx.robot}: no home reported yet, nowhere to return to")
    home, here = ctx.home, ctx.position
    alt = home.alt + ctx.rtl_height
    legs = []
    if here is not None:  # PX4's rule: climb to the return height where it is first, never descend to it
        if here.alt < alt - CLIMB_TOLERANCE_M and _metres(here, home) > HOME_RADIUS_M:
            legs.append(gri.Waypoint(lat=here.lat, lon=here.lon, alt=alt))
        alt = max(alt, here.alt)
    legs.append(gri.Waypoint(lat=home.lat, lon=home.lon, alt=alt))
    # the gateway lands it once this goto completes (RETURN_ACTION land, the default): gateway._rtl_home
    return Send(gri.Goto(waypoints=legs, speed=_speed(ctx)), "rtl")


CLIMB_TOLERANCE_M = 2.0
"""A return climbs first where it is only when more than this under its return height (the RAL's own return's
``altitude_tolerance_m``)."""
HOME_RADIUS_M = 8.0
"""Within this of home a return flies straight to home (the RAL's ``position_tolerance_m``)."""


def _metres(a: GeoPoint, b: GeoPoint) -> float:
    return distance_m(a.lat, a.lon, b.lat, b.lon)


def _reposition(ctx: Context, cmd: Command) -> Outcome:
    if (d := _needs(ctx, "goto", "go to a position")) is not None:
        return d
    lat, lon, z = cmd.p(5), cmd.p(6), cmd.p(7)
    if ctx.position is None and not (_finite(lat) and _finite(lon) and _finite(z)):
        return Deny(f"{ctx.robot}: no position reported yet; give latitude, longitude and altitude")
    here = ctx.position
    if not (_finite(lat) and _finite(lon)) or (cmd.frame in (mav.MAV_FRAME_GLOBAL_INT, *AMSL_FRAMES) and lat == 0
                                               and lon == 0):
        assert here is not None
        lat, lon = here.lat, here.lon
    try:
        alt = to_altitude_amsl(cmd.frame, z, ctx.home.alt if ctx.home else None, "reposition") if _finite(z) \
            else here.alt  # type: ignore[union-attr]
    except PlanError as exc:
        return Deny(str(exc))
    speed = cmd.p(1) if _finite(cmd.p(1)) and cmd.p(1) > 0 else _speed(ctx)
    try:
        return Send(gri.Goto(waypoints=[gri.Waypoint(lat=lat, lon=lon, alt=alt)], speed=speed))
    except Exception as exc:  # noqa: BLE001 - a value the contract refuses: say why
        return Deny(f"reposition: {exc}")


def _change_speed(ctx: Context, cmd: Command) -> Outcome:
    speed = cmd.p(2)
    if not _finite(speed) or speed <= 0:
        return Deny(f"set speed: {speed} m/s; give a positive speed (param2)")
    if ctx.running_path:
        kind = gri.FollowPath if ctx.running_role == "mission" else gri.Goto
        return Send(kind(waypoints=list(ctx.running_path), speed=speed), ctx.running_role, ctx.running_offset)
    if ctx.max_speed is not None and speed > ctx.max_speed:
        return Deny(f"set speed: {speed:g} m/s is above MAX_SPEED {ctx.max_speed:g} m/s")
    return Local("speed", (speed,))


def _gimbal(ctx: Context, pitch: float, yaw: float, current: tuple[float | None, float | None]) -> Outcome:
    if (d := _needs(ctx, "pan_tilt", "point a gimbal")) is not None:
        return d
    pan = yaw if _finite(yaw) else current[0]
    tilt = pitch if _finite(pitch) else current[1]
    if pan is None or tilt is None:
        return Deny("gimbal: give both pitch and yaw (the pan & tilt has not reported its angles)")
    if not (-180.0 <= pan < 180.0 and -90.0 <= tilt <= 90.0):
        return Deny(f"gimbal: yaw {pan:g} deg must be in [-180, 180), pitch {tilt:g} deg in [-90, 90]")
    return Send(gri.SetPanTilt(pan=pan, tilt=tilt))


def _set_mode(ctx: Context, cmd: Command) -> Outcome:
    base, main, sub = int(cmd.p(1)), int(cmd.p(2)), int(cmd.p(3)) if _finite(cmd.p(3)) else 0
    if not base & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return Deny("set mode: only custom modes are understood (PX4's main/sub mode numbers)")
    name = mode_name(main, sub)
    if name == "TAKEOFF":
        return _takeoff(ctx, Command(mav.MAV_CMD_NAV_TAKEOFF, (math.nan,) * 7))
    if name == "HOLD":
        return _hold(ctx)
    if name == "MISSION":
        return _mission_from(ctx, ctx.paused_at if ctx.paused_at is not None else ctx.mission_index)
    if name == "RTL":
        return _rtl(ctx)
    if name == "LAND":
        return _needs(ctx, "land", "land") or Send(gri.Land())
    shown = name or f"{main}/{sub}"
    return Deny(f"{ctx.robot} ({ctx.kind}) has no {shown} mode: its modes are the tasks it runs "
                f"(TAKEOFF, HOLD, MISSION, RTL, LAND; see docs/mavlink.md)")


def _hold(ctx: Context) -> Outcome:
    if (d := _needs(ctx, "hold", "hold")) is not None:
        return d
    return Send(gri.Hold(), "pause" if ctx.mission_running else "task")


def map_command(ctx: Context, cmd: Command, gimbal_now: tuple[float | None, float | None] = (None, None)) -> Outcome:
    c = cmd.command
    if c == mav.MAV_CMD_NAV_TAKEOFF:
        return _takeoff(ctx, cmd)
    if c == mav.MAV_CMD_NAV_LAND:
        return _needs(ctx, "land", "land") or Send(gri.Land())
    if c == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
        return _rtl(ctx)
    if c == mav.MAV_CMD_DO_REPOSITION:
        return _reposition(ctx, cmd)
    if c == mav.MAV_CMD_NAV_LOITER_UNLIM:
        return _hold(ctx)
    if c == mav.MAV_CMD_DO_PAUSE_CONTINUE:
        if int(cmd.p(1)) == 0:
            return _hold(ctx)
        if ctx.paused_at is None:
            return Deny(f"{ctx.robot}: no paused mission to continue")
        return _mission_from(ctx, ctx.paused_at)
    if c == mav.MAV_CMD_MISSION_START:
        first = int(cmd.p(1)) if _finite(cmd.p(1)) else 0
        index = _index_of_seq(ctx.plan, first) if first > 0 else ctx.mission_index
        return _mission_from(ctx, index)
    if c == mav.MAV_CMD_DO_SET_MISSION_CURRENT:
        index = _index_of_seq(ctx.plan, int(cmd.p(1)))
        if ctx.plan is None or index >= len(ctx.plan.waypoints):
            return Deny(f"{ctx.robot}: no mission waypoint at or after item {int(cmd.p(1))}")
        return _mission_from(ctx, index) if ctx.mission_running else Local("set_current", (index,))
    if c == mav.MAV_CMD_DO_SET_MODE:
        return _set_mode(ctx, cmd)
    if c == mav.MAV_CMD_DO_CHANGE_SPEED:
        return _change_speed(ctx, cmd)
    if c == mav.MAV_CMD_DO_MOUNT_CONTROL:
        return _gimbal(ctx, cmd.p(1), cmd.p(3), gimbal_now)
    if c == mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:
        return _gimbal(ctx, cmd.p(1), cmd.p(2), gimbal_now)
    if c == mav.MAV_CMD_DO_SET_ROI_LOCATION:
        if (d := _needs(ctx, "look_at", "look at a point")) is not None:
            return d
        try:
            alt = to_altitude_amsl(cmd.frame, cmd.p(7), ctx.home.alt if ctx.home else None, "region of interest")
            return Send(gri.LookAt(lat=cmd.p(5), lon=cmd.p(6), alt=alt))
        except (PlanError, Exception) as exc:  # noqa: BLE001 - a value the contract refuses: say why
            return Deny(str(exc))
    if c == mav.MAV_CMD_COMPONENT_ARM_DISARM:
        verb = "arm" if cmd.p(1) >= 0.5 else "disarm"
        return Deny(f"{ctx.robot} ({ctx.kind}) has no {verb} over the GRI: take-off starts the flight and landing "
                    "ends it")
    if c == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
        return Local("message_interval", (cmd.p(1), cmd.p(2)))
    if c == mav.MAV_CMD_REQUEST_MESSAGE:
        return Local("request_message", (cmd.p(1),))
    if c == mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
        return Local("request_message", (float(mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION),))
    return Deny(f"{command_name(c)} is not mapped to a cromat task", mav.MAV_RESULT_UNSUPPORTED)


MODES = tuple(PX4_MODES)
