"""A MAVLink mission as a cromat path: which items fly, at what altitude reference, and the running task's progress.

An uploaded mission becomes one ``follow_path`` (the RAL admits it as any path: clearance, ceiling, geofence,
speed). Its items:

| item | becomes |
| --- | --- |
| ``NAV_WAYPOINT`` (16) | a waypoint (hold time, acceptance radius, pass radius and yaw: not carried, must be 0/NaN) |
| ``DO_CHANGE_SPEED`` (178) | the path's speed (one speed for the whole path: a second, different one is refused) |
| ``NAV_TAKEOFF`` (22), first | started on the ground: a GRI ``take_off`` first (its height above home; 0/NaN: |
|                              | the robot's own), then the path; started airborne: skipped |
| ``NAV_LAND`` (21), last | once the path completes, a GRI ``land``; a latitude/longitude is one more waypoint |
|                         | (at the last one's altitude), landed at |
| ``NAV_RETURN_TO_LAUNCH`` (20), last | once the path completes, the gateway's return to launch (home, then land) |

QGroundControl's plans are shaped so (take-off, waypoints, land or return). Anything else (loiter, ROI, jumps, DO_
commands, a take-off or landing in the middle) is refused with the item and command named: a path task cannot
carry it, and silently dropping part of a mission would fly something the operator did not plan.

Altitude frames are converted explicitly: ``GLOBAL``/``GLOBAL_INT`` are metres above mean sea level (the DSP's
reference) and taken as they are; ``GLOBAL_RELATIVE_ALT``/``_INT`` are metres above home, so ``home.alt`` (the GRI
state's take-off point) is added; a robot that has not reported its home refuses them. Terrain and local frames are
refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bbcs.contracts import gri
from bbcs.geodesy import distance_m, valid_lat_lon
from cromat.mavlink.dialect import mav

AMSL_FRAMES = frozenset({mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_INT})
RELATIVE_FRAMES = frozenset({mav.MAV_FRAME_GLOBAL_RELATIVE_ALT, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})
INT_FRAMES = frozenset({mav.MAV_FRAME_GLOBAL_INT, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})


@dataclass(frozen=True, slots=True)
class Item:
    """One mission item as MISSION_ITEM_INT carries it (``x``/``y``: degrees × 10⁷)."""

    seq: int
    frame: int
    command: int
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    x: int = 0
    y: int = 0
    z: float = 0.0
    autocontinue: int = 1
    mission_type: int = 0


def item_of(msg: object) -> Item:
    """From MISSION_ITEM_INT or the legacy MISSION_ITEM (float degrees)."""
    is_int = msg.get_type() == "MISSION_ITEM_INT"  # type: ignore[attr-defined]
    x, y = msg.x, msg.y  # type: ignore[attr-defined]
    return Item(seq=msg.seq, frame=msg.frame, command=msg.command, param1=msg.param1,  # type: ignore[attr-defined]
                param2=msg.param2, param3=msg.param3, param4=msg.param4,  # type: ignore[attr-defined]
                x=int(x) if is_int else round(x * 1e7), y=int(y) if is_int else round(y * 1e7),
                z=float(msg.z), autocontinue=msg.autocontinue,  # type: ignore[attr-defined]
                mission_type=getattr(msg, "mission_type", 0))


def waypoint_item(seq: int, w: gri.Waypoint, mission_type: int = 0) -> Item:
    """A waypoint as an item in the AMSL frame (a download of a path the gateway did not upload)."""
    return Item(seq=seq, frame=mav.MAV_FRAME_GLOBAL_INT, command=mav.MAV_CMD_NAV_WAYPOINT,
                x=round(w.lat * 1e7), y=round(w.lon * 1e7), z=w.alt, mission_type=mission_type)


@dataclass(frozen=True, slots=True)
class Plan:
    """The path of a mission: its waypoints (AMSL) and, for each, the mission item it came from."""

    waypoints: tuple[gri.Waypoint, ...]
    seqs: tuple[int, ...]
    speed: float | None
    count: int
    """Items in the mission (MISSION_CURRENT's ``total``)."""
    takeoff: bool = False
    """The mission begins with NAV_TAKEOFF: started on the ground, it takes off first."""
    takeoff_height: float | None = None
    """That take-off's height above home (None: the robot's own take-off height)."""
    finish: str = ""
    """What follows the path's completion: ``land``, ``rtl`` or nothing."""


class PlanError(ValueError):
    """A mission that cannot be a path, with the item and the reason."""


def _blank(value: float) -> bool:
    return value == 0.0 or math.isnan(value)


def to_altitude_amsl(frame: int, z: float, home_alt: float | None, what: str) -> float:
    if frame in AMSL_FRAMES:
        return z
    if frame in RELATIVE_FRAMES:
        if home_alt is None:
            raise PlanError(f"{what}: its altitude is relative to home, and the robot has not reported its home yet")
        return home_alt + z
    raise PlanError(f"{what}: frame {frame_name(frame)} is not supported (use GLOBAL or GLOBAL_RELATIVE_ALT)")


def frame_name(frame: int) -> str:
    entry = mav.enums["MAV_FRAME"].get(frame)
    return entry.name.removeprefix("MAV_FRAME_") if entry else str(frame)


def command_name(command: int) -> str:
    entry = mav.enums["MAV_CMD"].get(command)
    return entry.name.removeprefix("MAV_CMD_") if entry else str(command)


def plan_of(items: list[Item], home_alt: float | None) -> Plan:
    """The path ``items`` describe, or PlanError naming the first item that cannot be part of one."""
    waypoints: list[gri.Waypoint] = []
    seqs: list[int] = []
    speed: float | None = None
    takeoff, takeoff_height, finish = False, None, ""
    last = items[-1].seq if items else -1
    for it in items:
        what = f"mission item {it.seq} ({command_name(it.command)})"
        if it.command == mav.MAV_CMD_NAV_TAKEOFF:
            if waypoints or takeoff:
                raise PlanError(f"{what}: a take-off is the mission's first flight item, once")
            takeoff, takeoff_height = True, _takeoff_height(it, home_alt, what)
        elif it.command in (mav.MAV_CMD_NAV_LAND, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH):
            if it.seq != last or not waypoints:
                raise PlanError(f"{what}: a landing or return ends the mission, after its waypoints "
                                "(a cromat path cannot carry one in its middle)")
            finish = "rtl" if it.command == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH else "land"
            end = waypoints[-1]
            lat, lon = it.x / 1e7, it.y / 1e7
            if finish == "land" and (it.x or it.y) and distance_m(lat, lon, end.lat, end.lon) > 1.0:
                waypoints.append(gri.Waypoint(lat=lat, lon=lon, alt=end.alt))  # its point, at the last altitude
                seqs.append(it.seq)
        elif it.command == mav.MAV_CMD_NAV_WAYPOINT:
            if not (_blank(it.param1) and _blank(it.param2) and _blank(it.param3) and _blank(it.param4)):
                raise PlanError(f"{what}: hold time, acceptance/pass radius and yaw are not carried by a cromat path "
                                "(leave them 0)")
            alt = to_altitude_amsl(it.frame, it.z, home_alt, what)
            lat, lon = it.x / 1e7, it.y / 1e7
            if not valid_lat_lon(lat, lon):
                raise PlanError(f"{what}: latitude {lat} / longitude {lon} out of range")
            waypoints.append(gri.Waypoint(lat=lat, lon=lon, alt=alt))
            seqs.append(it.seq)
        elif it.command == mav.MAV_CMD_DO_CHANGE_SPEED:
            value = it.param2
            if math.isnan(value) or value <= 0:
                raise PlanError(f"{what}: speed {value} m/s; give a positive speed (param2)")
            if speed is not None and abs(speed - value) > 1e-6:
                raise PlanError(f"{what}: a second speed ({value:g} m/s after {speed:g}); a cromat path has one speed")
            speed = value
        else:
            raise PlanError(f"{what}: a cromat path carries waypoints and one speed only; this item is not mapped")
    if not waypoints:
        raise PlanError("the mission has no waypoint")
    return Plan(tuple(waypoints), tuple(seqs), speed, len(items), takeoff, takeoff_height, finish)


def _takeoff_height(it: Item, home_alt: float | None, what: str) -> float | None:
    """A NAV_TAKEOFF item's altitude as a height above home; 0/NaN: the robot's own take-off height."""
    if _blank(it.z):
        return None
    if it.frame in RELATIVE_FRAMES:
        return it.z
    amsl = to_altitude_amsl(it.frame, it.z, home_alt, what)
    if home_alt is None:
        raise PlanError(f"{what}: its altitude is above mean sea level, and the robot has not reported its home yet")
    if amsl <= home_alt:
        raise PlanError(f"{what}: altitude {amsl:g} m AMSL is not above home ({home_alt:g} m)")
    return amsl - home_alt


# ---------------------------------------------------------------- progress of the running path


@dataclass(frozen=True, slots=True)
class Progress:
    current: int
    """Index (into the plan's waypoints) of the waypoint being flown to."""
    reached: int
    """How many of the plan's waypoints are reached (all before ``current``; all of them once completed)."""


def progress(offset: int, sent: int, queued: int | None, completed: bool) -> Progress:
    """Where a path task started at waypoint ``offset`` (``sent`` waypoints from there) is, from the DSP queue
    length in the telemetry (the queue holds the waypoint being flown to and those after it). Before the queue
    fills it reads 0: the task is at its first waypoint, not done; only the task's completion says done."""
    if completed:
        return Progress(current=offset + sent - 1, reached=offset + sent)
    if not queued:
        return Progress(current=offset, reached=offset)
    done = max(0, sent - min(queued, sent))
    return Progress(current=offset + done, reached=offset + done)
