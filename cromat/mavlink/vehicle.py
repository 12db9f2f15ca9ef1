"""One robot's MAVLink side: its system id, what the gateway knows of it (the manifest's .conf and limits), its
latest GRI state, its mission (stored items, the plan, the running mission's task) and its transfer state.

Only the gateway's loop thread touches a Vehicle. :meth:`Vehicle.context` is the view :func:`commands.map_command`
decides on; :meth:`Vehicle.mission_progress` is where the running mission stands (pure functions of the state).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

from bbcs.conf.parser import load_conf
from bbcs.contracts import gri
from cromat.mavlink import plan as pl
from cromat.mavlink.commands import Context, Role
from cromat.mavlink.dialect import Encoder, mav
from cromat.mavlink.mission import MissionTransfer
from cromat.mavlink.params import ParamTable, conf_params, number
from cromat.mavlink.telemetry import Schedule, movement_task

log = logging.getLogger("cromat.mavlink")


@dataclass
class RobotSpec:
    """What the gateway knows of a robot before it is seen: from its manifest (``--manifest``) and flags."""

    name: str
    sysid: int | None = None
    params: ParamTable = field(default_factory=ParamTable)
    takeoff_height: float | None = None
    max_speed: float | None = None
    battery_full_v: float | None = None
    battery_empty_v: float | None = None
    rtl_height: float = 10.0
    """The .conf's RETURN_HEIGHT (m above home): the return-to-launch flies home at least this high."""
    return_action: str = "land"
    """The .conf's RETURN_ACTION: ``land`` once home (the default, PX4's), or ``hover`` there."""


def spec_from_manifest(path: str) -> RobotSpec:
    """The robot's name, .conf values and limits from its launch manifest (its errors name file and line)."""
    from module_manager.manifest import load_manifest

    m = load_manifest(path, check_pki=False)
    doc = load_conf(m.conf)
    table = conf_params(doc)
    takeoff = doc.get("TAKEOFF_HEIGHT") or doc.get("TAKEOFF_HEIGHT_DEFAULT")
    max_speed = doc.get("MAX_SPEED")
    ral = next((mod.params for name, mod in m.raw.modules.items() if mod.entry == "ral" or name == "ral"), {})

    def num(value: object) -> float | None:
        return number(value) if isinstance(value, str) else None

    rtl = num(doc.get("RETURN_HEIGHT")) or num(ral.get("return_height_m"))  # the .conf's, as the RAL's return
    action = doc.get("RETURN_ACTION")
    return RobotSpec(name=m.robot, params=table, takeoff_height=num(takeoff), max_speed=num(max_speed),
                     battery_full_v=num(ral.get("battery_full_v")), battery_empty_v=num(ral.get("battery_empty_v")),
                     rtl_height=rtl or 10.0, return_action="hover" if action == "hover" else "land")


@dataclass
class MissionRun:
    """The path task the gateway started for the uploaded mission."""

    task_id: int
    offset: int
    sent: int
    completed: bool = False
    ended: bool = False
    finished: bool = False
    """The mission's end (its landing or return) was started after this run completed."""


class Vehicle:
    def __init__(self, spec: RobotSpec, sysid: int, encoder: Encoder, *, retry_s: float = 1.5) -> None:
        self.spec = spec
        self.robot = spec.name
        self.sysid = sysid
        self.encoder = encoder
        self.state: gri.GriState | None = None
        self.schedule = Schedule()
        self.stored: dict[int, list[pl.Item]] = {}
        self.transfer = MissionTransfer(self.stored, retry_s=retry_s)
        self.plan: pl.Plan | None = None
        self.mission_index = 0
        self.run: MissionRun | None = None
        self.paused_at: int | None = None
        self.pausing_at: int | None = None
        self.speed: float | None = None
        self.rtl_task = 0
        """The running return to launch's task (its goto, then its landing): shown as RTL."""
        self.rtl_landing: int | None = None
        """The return's landing: None before home is reached, 0 while asked, then its task id."""
        self.linked = False
        self.mission_takeoff: tuple[int, int] | None = None
        """The take-off a mission began with (its task id, the plan index its path starts at), until it ends."""
        """The gateway holds this robot's GRI link (a MAVLink ground station is heard)."""
        self.reached = 0
        """Mission items told reached (MISSION_ITEM_REACHED) for the current run."""
        self.seen_errors: set[tuple[str, int, float]] = set()
        self.pending: set[tuple] = set()
        """Commands sent to the RAL and not answered yet (a retransmission is answered IN_PROGRESS)."""
        self.param_queue: list[int] = []
        self.replacing: tuple[list[pl.Item], pl.Plan] | None = None
        """A mission uploaded while one flew, until the RAL admits its path."""
        self.boot = 0.0

    @property
    def kind(self) -> str:
        return self.state.kind if self.state else ""

    # ---------------------------------------------------------------- the view commands are decided on

    def context(self) -> Context:
        s = self.state
        remaining: tuple[gri.Waypoint, ...] = ()
        role: Role = "task"
        offset = 0
        task = movement_task(s) if s else None
        if task is not None and task.kind in ("goto", "follow_path") and task.params is not None:
            wps = tuple(task.params.waypoints)  # type: ignore[union-attr]
            queued = s.waypoints_queued if s else None
            done = max(0, len(wps) - queued) if queued else 0
            remaining = wps[done:]
            if self.run is not None and self.run.task_id == task.id:
                role, offset = "mission", self.run.offset + done
            elif task.id == self.rtl_task:
                role = "rtl"
        return Context(
            robot=self.robot, kind=self.kind, available=frozenset(s.available) if s else frozenset(),
            home=s.home if s else None, position=s.position if s else None, airborne=s.airborne if s else None,
            takeoff_height=self.spec.takeoff_height, max_speed=self.spec.max_speed, rtl_height=self.spec.rtl_height,
            plan=self.plan, mission_index=self.mission_index, mission_running=self.mission_running(),
            paused_at=self.paused_at, running_path=remaining, running_role=role, running_offset=offset,
            speed=self.speed)

    def mission_running(self) -> bool:
        if self.run is None or self.run.ended or self.state is None:
            return False
        return any(t.id == self.run.task_id and t.status == "running" for t in self.state.tasks)

    def mission_progress(self) -> pl.Progress | None:
        run = self.run
        if run is None or self.plan is None:
            return None
        queued = self.state.waypoints_queued if self.state else None
        return pl.progress(run.offset, run.sent, queued if self.mission_running() else 0, run.completed)

    def mission_current(self) -> tuple[int, int, int]:
        """MISSION_CURRENT's (seq, total, mission_state)."""
        if self.plan is None:
            return 0, 0, mav.MISSION_STATE_NO_MISSION
        total = self.plan.count
        prog = self.mission_progress()
        if self.paused_at is not None and not self.mission_running():
            index, state = self.paused_at, mav.MISSION_STATE_PAUSED
        elif prog is None:
            index, state = self.mission_index, mav.MISSION_STATE_NOT_STARTED
        elif self.run is not None and self.run.completed:
            index, state = prog.current, mav.MISSION_STATE_COMPLETE
        elif self.mission_running():
            index, state = prog.current, mav.MISSION_STATE_ACTIVE
        else:  # replaced, cancelled or failed: where it stopped
            index, state = prog.current, mav.MISSION_STATE_PAUSED
        index = min(max(index, 0), len(self.plan.seqs) - 1)
        return self.plan.seqs[index], total, state

    def newly_reached(self) -> list[int]:
        """Mission item seqs reached since the last call (MISSION_ITEM_REACHED, each once per run)."""
        prog = self.mission_progress()
        if prog is None or self.plan is None:
            return []
        out = [self.plan.seqs[i] for i in range(self.reached, min(prog.reached, len(self.plan.seqs)))]
        self.reached = max(self.reached, prog.reached)
        return out

    # ---------------------------------------------------------------- what the RAL said

    def pause_at(self) -> None:
        """Note the running mission's current waypoint as a pause is asked (the mission continues from there)."""
        prog = self.mission_progress() if self.mission_running() else None
        self.pausing_at = prog.current if prog is not None else None

    def started(self, role: Role, offset: int, reply: gri.TaskReply, request: gri.TaskRequest) -> None:
        if role == "mission":
            sent = len(request.waypoints)  # type: ignore[union-attr]
            self.run = MissionRun(reply.task_id, offset, sent)
            self.reached = offset
            self.paused_at = None
        elif role == "pause":
            # a pause with no mission running (a resend of one already answered) keeps where it was paused
            self.paused_at = (self.pausing_at if self.pausing_at is not None
                              else self.paused_at if self.paused_at is not None else self.mission_index)
            self.pausing_at = None
            if self.run is not None:
                self.run.ended = True
        elif role == "rtl":
            self.rtl_task = reply.task_id
            self.rtl_landing = None
        elif role == "mission_takeoff":
            self.mission_takeoff = (reply.task_id, offset)
            self.paused_at = None

    def on_event(self, event: gri.GriEvent) -> None:
        run = self.run
        if run is None or event.task_id != run.task_id:
            return
        if event.kind == "task_completed":
            run.completed = True
            run.ended = True
        elif event.kind in ("task_failed", "task_cancelled", "task_replaced", "aborted"):
            run.ended = True

    def set_plan(self, items: list[pl.Item], plan: pl.Plan | None) -> None:
        self.stored[mav.MAV_MISSION_TYPE_MISSION] = items
        self.plan = plan
        self.mission_index = 0
        self.paused_at = None
        if self.run is not None and not self.mission_running():
            self.run = None

    def download_items(self) -> list[pl.Item]:
        """What a mission download returns: the uploaded mission, else the robot's running path (the task book's)."""
        items = self.stored.get(mav.MAV_MISSION_TYPE_MISSION)
        if items:
            return items
        task = movement_task(self.state) if self.state else None
        if task is not None and task.params is not None and hasattr(task.params, "waypoints"):
            return [pl.waypoint_item(i, w) for i, w in enumerate(task.params.waypoints)]  # type: ignore[union-attr]
        return []


def describe(spec: RobotSpec) -> str:
    conf = Path(spec.params.conf).name if spec.params.conf else "no .conf"
    return f"{spec.name} ({conf}, {len(spec.params.params)} parameters)"
