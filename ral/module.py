"""The RAL process (``python -m ral``): serves the GRI, turns tasks into MRI requests to the manager.

This file holds the module itself (its slots, start and stop, the main loop's tick, the GRI state); its rooms are
mixins, each in its own file: ``ral/config.py`` (manifest parameters), ``ral/gri_service.py`` (task requests,
abort, restarts, the ground-station link and failsafe), ``ral/task_watch.py`` (the manager's task book followed,
tasks judged against telemetry), ``ral/drive_clients.py`` (speed acknowledgement, trajectory generator) and
``ral/fleet_glue.py`` (fleet allocation, world and synchronisation requests).

It is a bbcs :class:`~bbcs.module.Module` named ``ral`` so the manager launches and supervises it like any
other module. Its own output slots carry the data a task needs (the manifest's task map routes the robot's
modules to them): ``path`` (waypoints), ``speed``, ``pt_datos`` (pan & tilt angles or target point).

The RAL keeps no task book: the Module Manager's is the only record of the running task of each type. The RAL
translates a GRI task into an MRI ``SetTask`` carrying the task's typed parameters, and derives GRI events from
the manager's task lists (its replies and its robot state), so a task started by anyone is shown and announced.

Its inputs (the manager's state, the ground stations' tokens and heartbeats, the speed acknowledgement, the
trajectory generator's answers and paths) are handled on the module's one event loop, like any module's, in
arrival order with its ticks. One worker thread handles task queries and failsafe actions in arrival order: they
wait on bus round trips (the manager, the generator, the acknowledgement), which the loop must not. Data go out
only after the manager's reply, which comes after the module answered the task's mode: the data are handled under
that mode.
The main loop's tick judges the running tasks against telemetry (complete, stalled), fails those a module
error affects, advances the link-loss failsafe and publishes the GRI state.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, ClassVar

import msgspec
import zenoh
import zenoh.ext

from bbcs import (
    Direction,
    Kind,
    Module,
    ModuleContext,
    OutputSlot,
    Publisher,
    Safety,
    SlotSpec,
    keys,
    wire,
)
from bbcs.contracts import gri, mri
from bbcs.contracts import tasks as t
from bbcs.contracts.error_codes import LOSS_OF_CONTROL_CODES, RalErrorCode
from bbcs.contracts.errors import ErrorReport
from bbcs.contracts.pan_tilt import DatosPT
from bbcs.contracts.path_follower import (
    SPEED_ACK_SLOT,
    DatosSegCam,
    HeadingSegCam,
    RefsSegCam,
    SpeedAck,
    SpeedSegCam,
)
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.contracts.trajectory import TrajectoryRequest, TrajectoryStatus
from ral import faults as telemetry_faults
from ral import param_events
from ral.config import (
    MANAGER_STALE_S,
    MAX_ERRORS,
    TASKS_REFRESH_S,
    RalConfig,
    p_max_speed,
)
from ral.drive_clients import DriveClients
from ral.failsafe import FailsafeConfig, LinkEvent, LinkMonitor
from ral.fleet import FleetLink
from ral.fleet_glue import FleetGlue, WorldSyncJob
from ral.gri_service import GriService, events_publisher
from ral.health import HealthConfig, HealthMonitor, load_health, ral_conf_errors
from ral.task_watch import TaskWatch
from ral.tasks import (
    JudgeConfig,
    Limits,
    Progress,
    available_kinds,
    load_limits,
)


class Ral(GriService, TaskWatch, DriveClients, FleetGlue, Module):
    name: ClassVar[str] = "ral"
    slots = (
        OutputSlot("path", DatosSegCam, kind=Kind.STREAM),
        OutputSlot("speed", SpeedSegCam),
        OutputSlot("heading", HeadingSegCam),
        OutputSlot("pt_datos", DatosPT),
        OutputSlot("error", ErrorReport),
        OutputSlot("task", t.TaskData),  # the started task's parameters, for modules whose mode cannot carry them
    )
    error_slot = "error"
    tick_period = 0.05
    conf_errors = staticmethod(ral_conf_errors)
    """The RAL's check of its limits in the robot .conf (``cromat launch --check``, ``cromat conf check``)."""
    param_errors = staticmethod(RalConfig.param_errors)
    """The RAL's check of its manifest params (``cromat launch --check``, with the manifest's file:line)."""

    def __init__(self, context: ModuleContext, clock: Any = None) -> None:
        super().__init__(context)
        self.cfg, self.task_names = RalConfig.from_params(context.params)
        self.limits = load_limits(context.conf) if context.conf else Limits(max_speed=p_max_speed())
        self.health = HealthMonitor(load_health(context.conf) if context.conf else HealthConfig(),
                                    loss_codes=LOSS_OF_CONTROL_CODES.get(self.cfg.kind, frozenset()))
        """Loss of control seen in the robot's own telemetry (ral/health.py)."""
        self.clock = clock if clock is not None else self.bbcs_clock.time
        """The robot's clock (simulated time in lockstep, bbcs/clock.py): the task judge, stamps, state period."""
        self.link_clock = clock if clock is not None else time.time
        """The ground-station link is judged on the wall clock: a ground station is outside any simulation."""
        self._working = False
        self.judge_cfg = JudgeConfig(
            position_tolerance_m=self.cfg.position_tolerance_m,
            altitude_tolerance_m=self.cfg.altitude_tolerance_m,
            settle_s=self.cfg.settle_s,
            stall_s=self.cfg.stall_s,
            max_range_m=self.cfg.max_range_m,
        )
        self.link = LinkMonitor(
            FailsafeConfig(
                loss_timeout_s=self.cfg.failsafe_timeout_s,
                heartbeat_timeout_s=self.cfg.heartbeat_timeout_s,
                regain_s=self.cfg.regain_s,
                action=self.cfg.failsafe_action,
            )
        )
        self.available: dict[str, str] = {}
        """Manifest task → type, from the manager."""
        self.telemetry: RobotTelemetry | None = None
        self.home: GeoPoint | None = None
        # the manager's task book as last seen (a view: never changed here, only replaced by a newer one)
        self._epoch: float | None = None
        self._version = -1
        self._live: dict[int, t.TaskInfo] = {}
        self._finished: set[int] = set()
        self._progress: dict[int, Progress] = {}
        self._seen_errors = 0.0
        self._seen_params = param_events.Seen()
        self._telemetry_fault = telemetry_faults.TelemetryFault()
        """Refused DSP telemetry frames: they fail a task only when the fault persists (ral/faults.py)."""
        self._jobs: queue.Queue[Any] = queue.Queue()
        self._bus_lock = threading.Lock()
        self._manager_state: mri.RobotState | None = None
        self._manager_seen = 0.0
        self._manager_new = False
        self._manager_up = False
        self._error_log: deque[mri.ErrorEvent] = deque(maxlen=MAX_ERRORS)
        self._ral_entities: list[Any] = []
        self._worker: threading.Thread | None = None
        self._state_pub: Publisher[gri.GriState] | None = None
        self._event_pub: Publisher[gri.GriEvent] | None = None
        self._refs_pub: Publisher[RefsSegCam] | None = None
        self._next_state = 0.0
        self._tasks_fetched = 0.0
        self._speed_acks: list[SpeedAck] = []
        self._traj_pub: Publisher[TrajectoryRequest] | None = None
        self._traj_status: dict[int, TrajectoryStatus] = {}
        self._traj_paths: dict[str, tuple[int, tuple[t.Waypoint, ...]]] = {}
        """Generator output kind → (how many paths seen, the last path)."""
        self._traj_seen = threading.Condition()
        self._traj_next_id = int(time.time()) % 1_000_000 * 1000
        self._generated: dict[int, tuple[t.Waypoint, ...]] = {}
        """Task id → the path the generator planned for it (what a survey/orbit is judged on, ``ral.tasks.judge``)."""
        self._pt_sent: dict[int, float] = {}
        """Pan & tilt tasks (id) whose angles have not been seen reached → when they were last sent
        (``ral.tasks.pan_tilt_check``)."""
        self._pt_on_slot: int | None = None
        """The task whose datum the RAL last put on ``pt_datos`` (a resend, a tracked target, the data its mode did
        not carry); the value is withdrawn when that task ends: a pan & tilt datum belongs to its task, and one left
        on the slot would be read again by an input routed back to it, or by a module restarted later, with no task
        behind it (campaign seed 41)."""
        self._then: dict[int, t.TaskParams] = {}
        """A task to start once the task of this id completes (a fleet target after the take-off it needed)."""
        self.pt_resends = 0
        """Pan & tilt angles sent again because the telemetry showed the gimbal elsewhere."""
        self._speed_acked = threading.Condition()
        self._fleet: FleetLink | None = None

    # ------------------------------------------------------------ bus

    def on_start(self) -> None:
        s = self.session
        assert s is not None
        self._state_pub = Publisher(
            s,
            gri.state_key(self.robot),
            SlotSpec("state", gri.GriState, Direction.OUT, Kind.STATE, Safety.SAFE),
        )
        self._event_pub = events_publisher(s, self.robot)
        # the planner's and the bridge's modules as the manifest names them (RAL params ``planner``, ``refs_to``);
        # REFS is not routed (the seed's CONTROL_ENTRADA has no field for it): written on that module's own key
        planner, refs_to = self.cfg.planner, self.cfg.refs_to
        if planner:
            self._traj_pub = Publisher(
                s,
                keys.slot_key(self.robot, planner, "request"),
                SlotSpec("request", TrajectoryRequest, Direction.OUT, Kind.STREAM, Safety.SAFE),
            )
        if refs_to:
            self._refs_pub = Publisher(
                s,
                keys.slot_key(self.robot, refs_to, "refs"),
                SlotSpec("refs", RefsSegCam, Direction.OUT, Kind.STATE, Safety.UNSAFE),
            )
        on_loop = self._on_loop
        self._ral_entities = [
            zenoh.ext.declare_advanced_subscriber(
                s,
                mri.mri_key(self.robot, mri.STATE),
                on_loop(self._on_manager_state),
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            ),
            s.liveliness().declare_subscriber(gri.gcs_alive_key("*"), on_loop(self._on_gcs_token), history=True),
            s.declare_subscriber(gri.gcs_heartbeat_key("*"), on_loop(self._on_gcs_heartbeat)),
            *([s.declare_subscriber(keys.slot_key(self.robot, self.cfg.speed_ack_from, SPEED_ACK_SLOT),
                                    on_loop(self._on_speed_ack))] if self.cfg.speed_ack_from else []),
            *([s.declare_subscriber(keys.slot_key(self.robot, planner, "status"), on_loop(self._on_traj_status)),
               s.declare_subscriber(keys.slot_key(self.robot, planner, "survey"),
                                    on_loop(lambda sample: self._on_traj_path("survey", sample))),
               s.declare_subscriber(keys.slot_key(self.robot, planner, "orbit"),
                                    on_loop(lambda sample: self._on_traj_path("orbit", sample)))] if planner else []),
            # a task request is a job: admission waits on bus round trips (the manager, the generator, the speed
            # acknowledgement), which the loop must not, so the worker thread answers it
            s.declare_queryable(gri.task_key(self.robot), self._jobs.put),
            wire.declare_service_schemas(s, keys.ral_key(self.robot), lambda: {
                gri.state_key(self.robot): gri.GriState, gri.events_key(self.robot): gri.GriEvent,
                gri.task_key(self.robot): {"request": gri.TaskRequest, "reply": gri.TaskReply}}),
        ]
        self._worker = threading.Thread(target=self._work, name="ral.tasks", daemon=True)
        self._worker.start()
        self._jobs.put("refresh_tasks")
        self._fleet_start(s)
        self._world_sync_start()

    def on_stop(self) -> None:
        self._world_sync_stop()
        if self._fleet is not None:
            self._fleet.stop()
        self._jobs.put(None)
        if self._worker is not None:
            self._worker.join(5.0)
        for entity in reversed(self._ral_entities):
            entity.undeclare()
        self._ral_entities.clear()
        for pub in (self._state_pub, self._event_pub, self._refs_pub, self._traj_pub):
            if pub is not None:
                pub.close()

    def _on_loop(self, handler: Callable[[zenoh.Sample], None]) -> Callable[[zenoh.Sample], None]:
        """A Zenoh callback that hands each sample to the event loop: the RAL's inputs are handled there, one at a
        time in arrival order with its ticks (and counted as its activity in a lockstep step), never on Zenoh's
        threads. Only the task jobs, which wait on bus round trips, run on the worker thread."""
        call_soon = self.call_soon
        return lambda sample: call_soon(lambda: handler(sample))

    def _on_manager_state(self, sample: zenoh.Sample) -> None:
        try:
            state = msgspec.msgpack.decode(sample.payload.to_bytes(), type=mri.RobotState)
        except msgspec.MsgspecError as exc:
            self.log.warning("unreadable manager state dropped: %s", exc)
            return
        with self.lock:
            self._manager_state = state
            self._manager_seen = self.clock()
            self._manager_new = True
        self._take_manager_state(self._manager_seen)


    def emit(self, kind: str, *, task_id: int = 0, task_type: str = "", detail: str = "") -> None:
        event = gri.GriEvent(
            robot=self.robot,
            stamp=self.clock(),
            kind=kind,  # type: ignore[arg-type]
            task_id=task_id,
            task_type=task_type,
            detail=detail,
        )
        self.log.info("event %s %s %s", kind, task_type, detail)
        if self._event_pub is not None:
            with self._bus_lock:
                self._event_pub.publish(event)

    # ------------------------------------------------------------ the manager's task book, as events


    # ------------------------------------------------------------ main loop

    def _take_manager_state(self, now: float) -> None:
        """Follow the manager's newest state: its task book, home, errors, parameters, and every running task
        judged against its telemetry. Run on the loop as each state comes in, not only at the next tick: in
        lockstep the manager publishes a state per telemetry sample, and a tick judged whichever was newest when
        it ran, so two runs of one flight judged different samples (a survey completed 0.4 s apart)."""
        ms = self._manager_state
        if not self._manager_new or ms is None:
            return
        self._manager_new = False
        self._sync(ms.task_epoch, ms.task_version, ms.tasks, ms.ended)
        if ms.home is not None:
            with self.lock:  # the manager's record: a RAL restarted in flight still has the take-off point
                self.home = ms.home
        if ms.telemetry is not None:
            self._fold_telemetry(ms.telemetry, now)
        self._check_errors(ms)
        param_events.relay(ms, self._seen_params, self.emit)
        with self.lock:
            running = list(self._live.values())
        self._telemetry_fault, ends = telemetry_faults.judge(self._telemetry_fault, ms, running, now)
        for end in ends:
            self._jobs.put(end)

    def on_tick(self) -> None:
        now = self.clock()
        self._take_manager_state(now)
        ms = self._manager_state
        up = ms is not None and now - self._manager_seen <= MANAGER_STALE_S
        if up != self._manager_up:
            self._manager_up = up
            self.emit("manager_back" if up else "manager_lost")
            if up:
                self._jobs.put("refresh_tasks")
        if not self.available and now - self._tasks_fetched >= TASKS_REFRESH_S:
            self._tasks_fetched = now
            self._jobs.put("refresh_tasks")
        for event in self.link.update(self.link_clock()):
            self.emit(event.kind, detail=event.detail)
            if event.action is not None:
                self._jobs.put(event)
        if now >= self._next_state:
            self._next_state = now + self.cfg.state_period_s
            self._publish_state(now)
        if self._fleet is not None:
            self._fleet.tick()


    def _publish_state(self, now: float) -> None:
        ms = self._manager_state
        errors = sorted([*(ms.errors if ms else []), *self._error_log], key=lambda e: e.stamp)[-MAX_ERRORS:]
        with self.lock:
            tasks = sorted(self._live.values(), key=lambda i: i.task_type)
            kinds = available_kinds(self.available, self.task_names)
        state = gri.GriState(
            robot=self.robot,
            kind=(ms.kind if ms and ms.kind else self.cfg.kind),
            stamp=now,
            telemetry=ms.telemetry if ms else None,
            home=self.home,
            tasks=tasks,
            available=kinds,
            modules=list(ms.modules) if ms else [],
            errors=errors,
            link=self.link.state,
            manager_up=self._manager_up,
        )
        if self._state_pub is not None:
            with self._bus_lock:
                self._state_pub.publish(state)

    # ------------------------------------------------------------ worker: tasks and failsafe actions

    def _work(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            self._working = True
            try:
                if job == "refresh_tasks":
                    self._refresh_tasks()
                elif isinstance(job, LinkEvent):
                    self._run_failsafe(job)
                elif isinstance(job, mri.EndTask):
                    self._end(job)
                elif isinstance(job, WorldSyncJob):
                    job.run()
                elif callable(job):  # a fleet share to fly (ral/fleet.py)
                    job()
                else:
                    self._answer(job)
            except Exception:
                self.log.exception("RAL job failed")
            self._working = False

    def lockstep_busy(self) -> str:
        """Lockstep (docs/simulation.md): a task job queued or running (admission, MRI calls) holds the step."""
        return "task job" if self._working or not self._jobs.empty() else ""

    def _mri(self, verb: str, request: msgspec.Struct) -> mri.MriReply | None:
        assert self.session is not None
        try:
            reply = mri.call(self.session, self.robot, verb, request, self.cfg.mri_timeout_s)
        except mri.MriError as exc:
            self._record_error(RalErrorCode.MRI_NO_REPLY, str(exc))
            return None
        self._sync_list(reply.data)
        return reply

    def _record_error(self, code: int, detail: str) -> None:
        with self.lock:
            self._error_log.append(
                mri.ErrorEvent(module="ral", code=int(code), name=RalErrorCode(code).name, stamp=self.clock(),
                               detail=detail)
            )
            self.report_error(int(code), detail)


    # ------------------------------------------------------------ fleet allocation (issue 17, ral/fleet.py)


    # ------------------------------------------------------------ fleet time and shared world (issue 17)
    # ral/sync_bus.py (clock offsets, synchronised start, formation) and ral/world_bus.py (the world model)


def main(argv: list[str] | None = None) -> int:
    return Ral.main(argv)
