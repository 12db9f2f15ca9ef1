"""What ``cromat gcs watch`` shows: a pure function of the robots' GRI states, their events and vision status.

Every line fits the width given (80 columns by default). Per robot: mode, airborne, link and manager; position,
altitude, heading, speed and climb; pan/tilt, battery, vision; tasks; modules not up; the last errors with their
names. Below the robots, the last events stay on screen instead of being wiped by the next state.

The body's data come from the state's ``telemetry`` (:class:`bbcs.contracts.robot.RobotTelemetry`); the battery
is its ``battery_v`` (``battery -`` when the robot reports none).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from typing import Any

WIDTH = 80
ERRORS_SHOWN = 3
EVENTS_KEPT = 8

ErrorNamer = Callable[[str, int], str]


def _get(state: Any, name: str) -> Any:
    """The telemetry field ``name`` of a GRI state (None when the robot has sent no telemetry yet)."""
    tel = state.telemetry
    return getattr(tel, name) if tel is not None else None


def _num(value: float | None, fmt: str, unit: str = "") -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:{fmt}}{unit}"


def _clock(stamp: float) -> str:
    return time.strftime("%H:%M:%S", time.localtime(stamp))


def fit(line: str, width: int = WIDTH) -> str:
    return line if len(line) <= width else line[: width - 1] + "…"


def robot_lines(state: Any, *, vision: Any = None, error_name: ErrorNamer | None = None,
                now: float | None = None) -> list[str]:
    """The block of one robot."""
    mode = _get(state, "mode_name") or _get(state, "mode")
    airborne = _get(state, "airborne")
    flying = {True: "airborne", False: "on ground", None: "air ?"}[airborne]
    age = "" if now is None else f"  {max(0.0, now - state.stamp):.1f}s ago"
    lines = [f"{state.robot} [{state.kind or '?'}] {mode if mode is not None else 'mode ?'}  {flying}  "
             f"link {state.link}  manager {'up' if state.manager_up else 'DOWN'}  "
             f"wp {_num(_get(state, 'waypoints_queued'), 'd')}{age}"]
    pos, vel = _get(state, "position"), _get(state, "velocity")
    where = f"pos {pos.lat:.6f} {pos.lon:.6f} alt {pos.alt:.1f} m" if pos is not None else "pos unknown"
    heading = _get(state, "heading_deg")
    if heading is None and _get(state, "attitude") is not None:
        heading = _get(state, "attitude").yaw
    speed = math.hypot(vel.vn, vel.ve) if vel is not None else None
    climb = -vel.vd if vel is not None else None
    lines.append(f"  {where}  hdg {_num(heading, '.0f', '°')}  spd {_num(speed, '.1f')} m/s  "
                 f"vz {_num(climb, '+.1f')}")
    seen = "-"
    if vision is not None:
        seen = str(_field(vision, "state") or "?")
        conf = _field(vision, "confidence")
        if conf:
            seen += f" {conf:.2f}"
    lines.append(f"  pan {_num(_get(state, 'pan_deg'), '+.1f', '°')}  tilt {_num(_get(state, 'tilt_deg'), '+.1f', '°')}"
                 f"  battery {_num(_get(state, 'battery_v'), '.1f', ' V')}  vision {seen}")
    tasks = ", ".join(f"{t.task_type}:{t.kind}#{t.id} {t.status}" for t in state.tasks) or "none"
    lines.append(f"  tasks {tasks}")
    mods = list(state.modules)
    down = [f"{m.name} {m.state}" + (f" ({m.restarts} restarts)" if m.restarts else "")
            for m in mods if m.state != "up"]
    restarted = [f"{m.name}×{m.restarts}" for m in mods if m.state == "up" and m.restarts]
    summary = (f"{len(mods)} up" if not down else f"{len(mods) - len(down)}/{len(mods)} up; " + ", ".join(down))
    lines.append(f"  modules {summary}" + (f"; restarted {' '.join(restarted)}" if restarted else ""))
    for err in list(state.errors)[-ERRORS_SHOWN:]:
        name = err.name or (error_name(err.module, err.code) if error_name else "")
        lines.append(f"  error {_clock(err.stamp)} {err.module} {err.code} {name}".rstrip()
                     + (f": {err.detail}" if err.detail else ""))
    return lines


def _field(obj: Any, name: str) -> Any:
    return obj.get(name) if isinstance(obj, Mapping) else getattr(obj, name, None)


def event_line(ev: Any) -> str:
    task = f" {ev.task_type}#{ev.task_id}" if ev.task_id else (f" {ev.task_type}" if ev.task_type else "")
    return f"  {_clock(ev.stamp)} {ev.robot} {ev.kind}{task} {ev.detail}".rstrip()


def render(states: Mapping[str, Any], events: Iterable[Any] = (), *, vision: Mapping[str, Any] | None = None,
           error_name: ErrorNamer | None = None, now: float | None = None, width: int = WIDTH) -> list[str]:
    """Every robot (sorted by name), then the last events; no line longer than ``width``."""
    lines: list[str] = []
    for robot in sorted(states):
        lines += robot_lines(states[robot], vision=(vision or {}).get(robot), error_name=error_name, now=now)
    shown = list(events)[-EVENTS_KEPT:]
    lines.append(f"events (last {len(shown)}):" if shown else "events: none yet")
    lines += [event_line(ev) for ev in shown]
    return [fit(line, width) for line in lines]


class WatchScreen:
    """The watch's memory: the latest state and vision status per robot, the last events; ``lines()`` renders."""

    def __init__(self, *, error_name: ErrorNamer | None = None, width: int = WIDTH,
                 clock: Callable[[], float] = time.time) -> None:
        self.states: dict[str, Any] = {}
        self.vision: dict[str, Any] = {}
        self.events: deque[Any] = deque(maxlen=EVENTS_KEPT)
        self.error_name = error_name
        self.width = width
        self.clock = clock

    def state(self, state: Any) -> None:
        self.states[state.robot] = state

    def event(self, ev: Any) -> None:
        self.events.append(ev)

    def vision_status(self, robot: str, status: Any) -> None:
        self.vision[robot] = status

    def lines(self) -> list[str]:
        return render(self.states, self.events, vision=self.vision, error_name=self.error_name, now=self.clock(),
                      width=self.width)

    def robot(self, robot: str) -> list[str]:
        """One robot's block alone (what a piped watch prints per state)."""
        lines = robot_lines(self.states[robot], vision=self.vision.get(robot), error_name=self.error_name)
        return [fit(line, self.width) for line in lines]


def vision_key(robot: str) -> str:
    """Where a robot's vision module publishes its status (``*``: every robot)."""
    from bbcs import keys

    return keys.slot_pattern(robot, "vision", "status")
