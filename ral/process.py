"""The RAL process (``python -m ral``): serves the GRI, turns tasks into MRI requests to the manager.

It is a bbcs :class:`~bbcs.module.Module` named ``ral`` so the manager launches and supervises it like any
other module. Its own output slots carry the data a task needs (the manifest's task map routes the robot's
modules to them): ``path`` (waypoints), ``speed``, ``pt_datos`` (pan & tilt angles or target point).

The RAL keeps no task book: the Module Manager's is the only record of the running task of each type. The RAL
translates a GRI task into an MRI ``SetTask`` carrying the task's typed parameters, and derives GRI events from
the manager's task lists (its replies and its robot state), so a task started by anyone is shown and announced.

One worker thread handles task queries and failsafe actions in arrival order. Data go out only after the
manager's reply, which comes after the module answered the task's mode: the data are handled under that mode.
The main loop's tick judges the running tasks against telemetry (complete, stalled), fails those a module
error affects, advances the link-loss failsafe and publishes the GRI state.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import deque
from typing import Any, ClassVar

import msgspec
import zenoh
import zenoh.ext

from bbcs import keys, wire
from bbcs.context import ModuleContext
from bbcs.contracts import gri, mri
from bbcs.contracts import tasks as t
from bbcs.contracts.dsp import FORWARDED_DSP_ERROR_BASE, MAX_SPEED_LIMIT, LinkErrorCode
from bbcs.contracts.error_codes import RalErrorCode, error_name
from bbcs.contracts.errors import ErrorReport
from bbcs.contracts.pan_tilt import DatosPT
from bbcs.contracts.path_follower import (
    SPEED_ACK_SLOT,
    DatoPuntoSegCam,
    DatosSegCam,
    HeadingSegCam,
    RefsSegCam,
    SpeedAck,
    SpeedSegCam,
)
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.contracts.trajectory import GeoPoint as TrajPoint
from bbcs.contracts.trajectory import OrbitRequest, SurveyRequest, TrajectoryRequest, TrajectoryStatus
from bbcs.module import Module
from bbcs.params import raise_first, struct_param_errors
from bbcs.signing import FleetTrust
from bbcs.slots import Direction, Kind, OutputSlot, Publisher, Safety, SlotSpec
from ral import faults as telemetry_faults
from ral import param_events
from ral.failsafe import FailsafeAction, FailsafeConfig, LinkEvent, LinkMonitor
from ral.fleet import FleetLink, can_do_from, goto_of, own_state_of
from ral.fleet_protocol import Execute, FleetConfig, OwnState
from ral.health import HealthConfig, HealthFault, HealthMonitor, load_health, ral_conf_errors
from ral.tasks import (
    JudgeConfig,
    Limits,
    Plan,
    Progress,
    Rejected,
    admit,
    after_completed,
    available_kinds,
    judge,
    load_limits,
    pan_tilt_check,
    return_request,
)

MAX_ERRORS = 20
HARMLESS_CODES = frozenset({FORWARDED_DSP_ERROR_BASE + LinkErrorCode.FLUSHED})
"""Module errors that do not affect a running task (unsent commands dropped because an abort overtook them)."""
MANAGER_STALE_S = 3.0
TASKS_REFRESH_S = 1.0
RESTART_REPLY_S = 4.0
"""A module restart is answered within this, below a ground station's default 5 s wait: as the manager confirmed
it by then, else as under way (its outcome follows as a ``module_restarted`` event or an error)."""
RESTART_CONFIRM_S = 60.0
"""How long the manager's confirmation of a restart is awaited (it answers once the module is up and linked)."""


class RalConfig(msgspec.Struct, frozen=True, kw_only=True):
    """The RAL's manifest parameters (``params`` of its module entry; ``task.<kind> = <manifest task>``)."""

    failsafe_action: FailsafeAction = FailsafeAction.HOLD
    failsafe_timeout_s: float = 10.0
    heartbeat_timeout_s: float = 2.0
    regain_s: float = 1.0
    position_tolerance_m: float = 3.0
    altitude_tolerance_m: float = 2.0
    settle_s: float = 2.0
    max_range_m: float = 20_000.0
    stall_s: float = 30.0
    """A movement task that makes no progress for this long fails (task_failed)."""
    mri_timeout_s: float = mri.REPLY_TIMEOUT_S
    """Must exceed the manager's ack wait (``mri.MANAGER_ACK_S``), else a task can be applied after being refused."""
    state_period_s: float = 0.2
    speed_ack_s: float = 3.0
    """How long the RAL waits for the answer to a path's speed before the path is not sent."""
    speed_ack_from: str = ""
    """The module whose ``speed_ack`` slot answers the RAL's speeds (the UAV: ``path_follower``); empty: the robot's
    speed and path reach one consumer in order and nothing is waited for (the manifest says which)."""
    kind: str = ""
    """Robot kind shown in the GRI state when the manager's state has none."""
    fleet_can_do: str = ""
    """Fleet target kinds this robot bids on, comma-separated (``none``: never); empty: ``visit`` if it has goto."""
    fleet_bid_window_s: float = 2.0
    """Longest wait for every live RAL's bid before a fleet round is decided without it (ral/fleet.py)."""
    battery_full_v: float = 0.0
    """Pack voltage at a full charge (the UAV's 6S LiPo: 25.2 V); with ``battery_empty_v``, turns the telemetry's
    ``battery_v`` into the state of charge a fleet bid weighs (ral/fleet.py ``state_of_charge``). 0: no estimate,
    bids carry no battery."""
    battery_empty_v: float = 0.0
    """Pack voltage taken as empty (below the full one)."""
    fleet_ca: str = ""
    """Set by the launch on a secured robot (``[bus.tls]``): the fleet CA (PEM) a ground station's certificate must
    be issued by for this RAL to adopt a fleet task it signed (bbcs/signing.py). Empty on a TLS bus: the bus's CA."""
    fleet_signers: str = ""
    """Set by the launch with ``fleet_ca``: the ground-station identities (``[bus.tls] gcs``, comma-separated) whose
    signature makes a fleet task adoptable; none on a TLS bus: every fleet task is refused."""
    fleet_crl: str = ""
    """Set by the launch with ``fleet_ca``: the fleet CA's revocation list (PEM, ``cromat certs --revoke``); a
    station whose certificate it lists signs nothing this RAL adopts. Read again when the file changes; missing:
    nothing revoked."""
    sync_clock_offset_s: float = 0.0
    """Tests only: this robot's fleet-time clock runs this far from the host's (docs/sync.md)."""
    sync_clock_drift_ppm: float = 0.0
    """Tests only: and drifts this much (parts per million)."""

    @classmethod
    def param_errors(cls, params: dict[str, str]) -> list[tuple[str, str]]:
        """Every problem of the manifest's RAL ``params``, (key, reason) (``cromat launch --check``: file:line)."""
        plain = {k: v for k, v in params.items() if not k.startswith("task.")}
        errors = struct_param_errors(cls, plain, what="RAL")
        if errors:
            return errors
        cfg = msgspec.convert(plain, cls, strict=False)
        if (cfg.battery_full_v or cfg.battery_empty_v) and not 0.0 <= cfg.battery_empty_v < cfg.battery_full_v <= 100.0:
            errors.append(("battery_full_v" if "battery_full_v" in plain else "battery_empty_v", (
                f"bad RAL parameter: battery_empty_v = {cfg.battery_empty_v:g} and battery_full_v = "
                f"{cfg.battery_full_v:g} must be volts with 0 <= empty < full <= 100 (both, or neither)")))
        if cfg.mri_timeout_s <= mri.MANAGER_ACK_S:
            errors.append(("mri_timeout_s", (
                f"bad RAL parameter: mri_timeout_s = {cfg.mri_timeout_s:g} must exceed the manager's ack wait "
                f"({mri.MANAGER_ACK_S:g} s), or a task could be applied after the ground station was told it failed")))
        return errors

    @classmethod
    def from_params(cls, params: dict[str, str]) -> tuple[RalConfig, dict[str, str]]:
        """The RAL's configuration; a :class:`bbcs.params.ParamError` (exit ``EXIT_CONFIG``: not restarted) naming
        every problem :meth:`param_errors` finds."""
        raise_first(cls.param_errors(params), source="manifest params of the RAL")
        plain = {k: v for k, v in params.items() if not k.startswith("task.")}
        names = {k.removeprefix("task."): v for k, v in params.items() if k.startswith("task.")}
        cfg = msgspec.convert(plain, cls, strict=False)
        return cfg, names


EVENTS_REPLAY = 256
"""GRI events the RAL keeps for a ground station that missed them while its link to the robot was cut: the
ground station's subscriber (``Gcs.events``) asks for them once the link is back (docs/gcs.md)."""


def events_publisher(session: zenoh.Session, robot: str) -> Publisher[gri.GriEvent]:
    """The robot's GRI event stream: a safe stream whose last ``EVENTS_REPLAY`` events are kept for replay."""
    return Publisher(session, gri.events_key(robot),
                     SlotSpec("events", gri.GriEvent, Direction.OUT, Kind.STREAM, Safety.SAFE), replay=EVENTS_REPLAY)


class Ral(Module):
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
        self.health = HealthMonitor(load_health(context.conf) if context.conf else HealthConfig())
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
        self._then: dict[int, t.TaskParams] = {}
        """A task to start once the task of this id completes (a fleet target after the take-off it needed)."""
        """Pan & tilt tasks (id) whose angles have not been seen reached → when they were last sent
        (``ral.tasks.pan_tilt_check``)."""
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
        # REFS is not routed (the seed's CONTROL_ENTRADA has no field for it): written on the follower's own key
        self._traj_pub = Publisher(
            s,
            keys.slot_key(self.robot, "trajectory", "request"),
            SlotSpec("request", TrajectoryRequest, Direction.OUT, Kind.STREAM, Safety.SAFE),
        )
        self._refs_pub = Publisher(
            s,
            keys.slot_key(self.robot, "path_follower", "refs"),
            SlotSpec("refs", RefsSegCam, Direction.OUT, Kind.STATE, Safety.UNSAFE),
        )
        self._ral_entities = [
            zenoh.ext.declare_advanced_subscriber(
                s,
                mri.mri_key(self.robot, mri.STATE),
                self._on_manager_state,
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            ),
            s.liveliness().declare_subscriber(gri.gcs_alive_key("*"), self._on_gcs_token, history=True),
            s.declare_subscriber(gri.gcs_heartbeat_key("*"), self._on_gcs_heartbeat),
            *([s.declare_subscriber(keys.slot_key(self.robot, self.cfg.speed_ack_from, SPEED_ACK_SLOT),
                                    self._on_speed_ack)] if self.cfg.speed_ack_from else []),
            s.declare_subscriber(keys.slot_key(self.robot, "trajectory", "status"), self._on_traj_status),
            s.declare_subscriber(keys.slot_key(self.robot, "trajectory", "survey"),
                                 lambda sample: self._on_traj_path("survey", sample)),
            s.declare_subscriber(keys.slot_key(self.robot, "trajectory", "orbit"),
                                 lambda sample: self._on_traj_path("orbit", sample)),
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
        for pub in (self._state_pub, self._event_pub, self._refs_pub):
            if pub is not None:
                pub.close()

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

    def _on_speed_ack(self, sample: zenoh.Sample) -> None:
        try:
            ack = msgspec.msgpack.decode(sample.payload.to_bytes(), type=SpeedAck)
        except msgspec.MsgspecError:
            return
        with self._speed_acked:
            self._speed_acks.append(ack)
            del self._speed_acks[:-16]
            self._speed_acked.notify_all()

    def _on_traj_status(self, sample: zenoh.Sample) -> None:
        try:
            status = msgspec.msgpack.decode(sample.payload.to_bytes(), type=TrajectoryStatus)
        except msgspec.MsgspecError:
            return
        with self._traj_seen:
            self._traj_status[status.request_id] = status
            while len(self._traj_status) > 32:
                del self._traj_status[next(iter(self._traj_status))]
            self._traj_seen.notify_all()

    def _on_traj_path(self, kind: str, sample: zenoh.Sample) -> None:
        try:
            path = msgspec.msgpack.decode(sample.payload.to_bytes(), type=DatosSegCam)
        except msgspec.MsgspecError:
            return
        points = tuple(t.Waypoint(lat=p.latitud, lon=p.longitud, alt=p.altura) for p in path.puntos)
        with self._traj_seen:
            count = self._traj_paths.get(kind, (0, ()))[0] + 1
            self._traj_paths[kind] = (count, points)
            self._traj_seen.notify_all()

    def _request_path(self, req: t.Survey | t.Orbit, task_id: int) -> str | None:
        """Ask the trajectory generator for the task's path (the task already runs, so the path follower reads
        the generator's output) and wait for its answer and its path: None, or the reason it failed."""
        assert self._traj_pub is not None
        kind = t.kind_of(req)
        pos = self.telemetry.position if self.telemetry else None
        start = TrajPoint(lat=pos.lat, lon=pos.lon) if pos is not None else None
        with self._traj_seen:
            self._traj_next_id = (self._traj_next_id + 1) % 2**31
            request_id = self._traj_next_id
            paths_before = self._traj_paths.get(kind, (0, ()))[0]
        if isinstance(req, t.Survey):
            request = TrajectoryRequest(request_id=request_id, survey=SurveyRequest(
                polygon=[TrajPoint(lat=v.lat, lon=v.lon) for v in req.polygon], height=req.height,
                overlap=req.overlap, start=start))
        else:
            request = TrajectoryRequest(request_id=request_id, orbit=OrbitRequest(
                centre=TrajPoint(lat=req.lat, lon=req.lon), radius=req.radius, height=req.height,
                clockwise=req.clockwise, turns=req.turns))
        self._traj_pub.publish(request)
        deadline = time.monotonic() + self.cfg.mri_timeout_s
        with self._traj_seen:
            answered = self._traj_seen.wait_for(lambda: request_id in self._traj_status,
                                                timeout=max(0.0, deadline - time.monotonic()))
            if not answered:
                return f"the trajectory generator did not answer the {kind} request within {self.cfg.mri_timeout_s:g} s"
            status = self._traj_status[request_id]
            if not status.accepted:
                return f"the trajectory generator refused the {kind}: {status.reason}"
            got = self._traj_seen.wait_for(lambda: self._traj_paths.get(kind, (0, ()))[0] > paths_before,
                                           timeout=max(0.0, deadline - time.monotonic()))
            if not got:
                return f"the trajectory generator accepted the {kind} but its path did not arrive"
            self._generated[task_id] = self._traj_paths[kind][1]
        return None

    def _send_speed(self, speed: float) -> str | None:
        """Publish a path's speed and wait until the path follower answered it (its SET_SPEED is then on the DSP
        command stream, ahead of any path sent after): None, or why the path must not go out. The speed input is
        best-effort, so it is published again every half second until answered."""
        if not self.cfg.speed_ack_from:
            self.publish("speed", SpeedSegCam(speed=speed))
            return None
        deadline = time.monotonic() + self.cfg.speed_ack_s
        with self._speed_acked:
            self._speed_acks.clear()
        while True:
            self.publish("speed", SpeedSegCam(speed=speed))
            with self._speed_acked:
                self._speed_acked.wait_for(
                    lambda: any(a.speed == speed for a in self._speed_acks),
                    timeout=max(0.0, min(0.5, deadline - time.monotonic())),
                )
                ack = next((a for a in self._speed_acks if a.speed == speed), None)
            if ack is not None:
                if ack.accepted:
                    return None
                return f"{self.cfg.speed_ack_from} refused speed {speed:g} m/s (code {ack.code}): {ack.reason}"
            if time.monotonic() >= deadline:
                return (f"{self.cfg.speed_ack_from} did not acknowledge speed {speed:g} m/s within "
                        f"{self.cfg.speed_ack_s:g} s; the path was not sent")

    def _on_gcs_token(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:  # a station that leaves stops linking every robot
            name = str(sample.key_expr).rsplit("/", 1)[-1]
            with self.lock:
                self.link.token(name, False)

    def _on_gcs_heartbeat(self, sample: zenoh.Sample) -> None:
        """A station links this robot only while its heartbeats name it (the link is per robot)."""
        try:
            beat = gri.decode_heartbeat(sample.payload.to_bytes())
        except msgspec.MsgspecError:
            return
        if self.robot not in beat.robots:
            return
        with self.lock:
            self.link.token(beat.gcs, True)
            self.link.heartbeat(self.link_clock())

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

    def _sync(self, epoch: float, version: int, active: list[t.TaskInfo], ended: list[t.TaskInfo]) -> None:
        """Fold in a task list from the manager; announce what started and what ended since the last one."""
        out: list[tuple[str, t.TaskInfo, str]] = []
        with self.lock:
            if self._epoch is not None and epoch != self._epoch:
                for info in self._live.values():
                    out.append(("task_failed", info, "Module Manager restarted: the task was lost"))
                    self._finished.add(info.id)
                self._live.clear()
                self._progress.clear()
                self._version = -1
            self._epoch = epoch
            if version <= self._version:
                pass  # an older (or the same) list: what it says is already known
            else:
                self._version = version
                for info in ended:
                    if info.id in self._finished:
                        continue
                    self._finished.add(info.id)
                    self._live.pop(info.id, None)
                    self._progress.pop(info.id, None)
                    self._generated.pop(info.id, None)
                    out.append((END_EVENTS[info.status], info, info.detail))
                for info in active:
                    if info.id not in self._live and info.id not in self._finished:
                        self._live[info.id] = info
                        self._progress[info.id] = Progress(started=self.clock())
                        out.append(("task_accepted", info, f"{info.kind or '-'} as {info.name} ({info.origin})"))
                gone = set(self._live) - {i.id for i in active}
                for task_id in gone:  # ended but no longer in the bounded history
                    info = self._live.pop(task_id)
                    self._progress.pop(task_id, None)
                    self._finished.add(task_id)
                    out.append(("task_cancelled", info, "ended (no record of how)"))
        for kind, info, detail in out:
            self.emit(kind, task_id=info.id, task_type=info.task_type, detail=detail)

    def _sync_list(self, data: Any) -> None:
        if isinstance(data, mri.TaskList):
            with self.lock:
                self.available = dict(data.available)
            self._sync(data.epoch, data.version, data.active, data.ended)

    # ------------------------------------------------------------ main loop

    def on_tick(self) -> None:
        now = self.clock()
        ms = self._manager_state
        if self._manager_new and ms is not None:
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

    def _fold_telemetry(self, tel: RobotTelemetry, now: float) -> None:
        """Judge every running task against new telemetry; a verdict goes to the manager as an EndTask."""
        with self.lock:
            self.telemetry = tel
            if tel.airborne is False and tel.position is not None:
                self.home = tel.position
            verdicts = []
            resend = []
            for task_id, info in self._live.items():
                v = judge(info, self._progress[task_id], tel, self.home, self.limits, self.judge_cfg, now,
                          generated=self._generated.get(task_id))
                self._progress[task_id] = v.progress
                if v.status != "running":
                    verdicts.append((info, v.status, v.detail))
                elif task_id in self._pt_sent:
                    check = pan_tilt_check(info.params, tel, self._pt_sent[task_id], now)
                    if check == "there":
                        del self._pt_sent[task_id]  # arrived: whatever moves the gimbal later is not fought
                    elif check == "resend":
                        self._pt_sent[task_id] = now
                        resend.append(info.params)
            for task_id in set(self._pt_sent) - set(self._live):
                del self._pt_sent[task_id]
            faults = self.health.update(tel, list(self._live.values()), self.home)
        for req in resend:
            assert isinstance(req, t.SetPanTilt)
            self.pt_resends += 1
            self.log.info("pan & tilt at %s/%s, not at the task's %g/%g: its angles sent again", tel.pan_deg,
                          tel.tilt_deg, req.pan, req.tilt)
            self.publish("pt_datos", DatosPT(ref_pan=req.pan, ref_tilt=req.tilt))
        for info, status, detail in verdicts:
            self._jobs.put(mri.EndTask(task_type=info.task_type, task_id=info.id, status=status, detail=detail))
        for fault in faults:
            self._health_fault(fault)

    def _health_fault(self, fault: HealthFault) -> None:
        """A loss of control in the robot's own telemetry (ral/health.py): an error with its severity on the GRI
        (published now), the running movement tasks failed with the reason, the robot's health action run as a
        failsafe."""
        code = RalErrorCode.LOSS_OF_CONTROL
        with self.lock:
            self._error_log.append(mri.ErrorEvent(module="ral", code=int(code), name=code.name, stamp=self.clock(),
                                                  detail=fault.detail, severity=fault.severity))
            self._next_state = 0.0
        self.report_error(int(code), fault.detail)
        for info in fault.fail:
            self._jobs.put(mri.EndTask(task_type=info.task_type, task_id=info.id, status="failed",
                                       detail=fault.detail))
        if fault.action is not None:
            self.emit("failsafe", detail=f"{fault.detail}: {fault.action}")
            self._jobs.put(LinkEvent("failsafe", fault.detail, action=fault.action))

    def _check_errors(self, ms: mri.RobotState) -> None:
        """A module error after a task started fails the running tasks of the types that module serves."""
        serves = {m.name: set(m.task_types) for m in ms.modules}
        fresh = [e for e in ms.errors if e.stamp > self._seen_errors and e.code not in HARMLESS_CODES
                 and not telemetry_faults.is_telemetry_refusal(e)]  # not fatal alone: ral/faults.py
        if not fresh:
            return
        self._seen_errors = max(e.stamp for e in fresh)
        with self.lock:
            running = list(self._live.values())
        for info in running:
            for e in fresh:
                if info.task_type in serves.get(e.module, set()) and e.stamp >= info.started:
                    name = e.name or error_name(e.module, e.code)  # the manager's records carry the bare code
                    detail = f"module {e.module} reported error {e.code}{' ' + name if name else ''}"
                    self._jobs.put(mri.EndTask(task_type=info.task_type, task_id=info.id, status="failed",
                                               detail=detail))
                    break

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

    def _refresh_tasks(self) -> None:
        self._mri("tasks", mri.ListTasks())

    def _end(self, request: mri.EndTask) -> None:
        """End a task the RAL judged completed or failed (only if it is still that task); then start what follows
        a completed one (the return failsafe's landing, ``ral.tasks.after_completed``)."""
        with self.lock:
            info = self._live.get(request.task_id)
        reply = self._mri("task", request)
        if reply is not None and reply.ok and request.status == "failed":
            self._record_error(RalErrorCode.TASK_FAILED, f"task {request.task_id}: {request.detail}")
        with self.lock:
            then = self._then.pop(request.task_id, None)
        follow = after_completed(info, self.limits) if info is not None and request.status == "completed" else None
        if request.status == "completed" and then is not None:
            follow = then
        if follow is not None and info is not None and reply is not None and reply.ok:
            answer = self.handle(follow, origin=info.origin)
            self.log.info("%s after task %d: %s", t.kind_of(follow), request.task_id,
                          "accepted" if answer.accepted else f"refused: {answer.reason}")

    def _answer(self, query: zenoh.Query) -> None:
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            try:
                request = gri.decode_request(payload)
            except msgspec.MsgspecError as exc:
                reply = gri.TaskReply(accepted=False, reason=f"invalid or unknown task: {exc}")
                self.emit("task_rejected", detail=reply.reason)
            else:
                reply = self.handle(request)
            wire.reply(query, gri.task_key(self.robot), reply)
        finally:
            query.drop()

    def handle(self, request: gri.TaskRequest, origin: t.Origin = "gcs") -> gri.TaskReply:
        """Admit, start in the manager's task book, send the task's data; the reply says accepted or why not."""
        if isinstance(request, gri.Abort):
            return self._abort()
        if isinstance(request, gri.Cancel):
            return self._cancel(request.task_type)
        if isinstance(request, gri.RestartModule):
            return self._restart(request.module)
        why = self._world_refusal(request)
        if why is not None:
            self.emit("task_rejected", detail=why)
            return gri.TaskReply(accepted=False, reason=why)
        if not self.available:
            self._refresh_tasks()
        with self.lock:
            plan = admit(request, available=self.available, task_names=self.task_names, limits=self.limits,
                         cfg=self.judge_cfg, telemetry=self.telemetry, home=self.home)
        if isinstance(plan, Rejected):
            self.emit("task_rejected", detail=plan.reason)
            return gri.TaskReply(accepted=False, reason=plan.reason)
        reply = self._mri("task", mri.SetTask(name=plan.name, params=plan.params, origin=origin))
        if reply is None or not reply.ok:
            reason = (
                "Module Manager did not answer"
                if reply is None
                else f"task {plan.name!r} refused: {reply.reason}"
            )
            if reply is not None:
                self._record_error(RalErrorCode.MRI_REFUSED, reason)
            self.emit("task_rejected", task_type=plan.task_type, detail=reason)
            return gri.TaskReply(accepted=False, reason=reason, task_type=plan.task_type,
                                 code=reply.code if reply else None)
        running = next((i for i in reply.data.active if i.task_type == plan.task_type), None) if isinstance(
            reply.data, mri.TaskList) else None
        task_id = running.id if running else 0
        problem = self._publish_data(plan, task_id)
        if problem is not None:
            if running is not None:
                self._end(mri.EndTask(task_type=plan.task_type, task_id=task_id, status="failed", detail=problem))
            self.emit("task_rejected", task_type=plan.task_type, detail=problem)
            return gri.TaskReply(accepted=False, reason=problem, task_id=task_id, task_type=plan.task_type)
        if origin == "gcs":
            with self.lock:  # an operator's task replaces the failsafe: fleet bids resume (ral/failsafe.py)
                cleared = self.link.clear_failsafe()
            if cleared:
                self.log.info("failsafe cleared by the operator's task %d", task_id)
        return gri.TaskReply(accepted=True, task_id=task_id, task_type=plan.task_type)

    def _publish_data(self, plan: Plan, task_id: int = 0) -> str | None:
        """The task's data, after the manager's reply (so after the module answered the task's mode). A path's
        speed goes first and is acknowledged before the path (docs/gcs.md, "Speed before path"). Returns None, or
        why the task's data could not go out."""
        req = plan.params
        self.publish("task", t.TaskData(task_id=task_id, params=req))
        if isinstance(req, t.Goto | t.FollowPath | t.FollowVisionPath | t.Survey | t.Orbit):
            assert req.speed is not None, "admission fills in the cruise speed"
            problem = self._send_speed(req.speed)
            if problem is not None:
                return problem
        if isinstance(req, t.Survey | t.Orbit):
            return self._request_path(req, task_id)
        if isinstance(req, t.FollowPath) and req.heading is not None:
            self.publish("heading", HeadingSegCam(heading=req.heading))
        if isinstance(req, t.Goto | t.FollowPath):
            points = [DatoPuntoSegCam(latitud=w.lat, longitud=w.lon, altura=w.alt) for w in req.waypoints]
            self.publish("path", DatosSegCam(n_points=len(points), puntos=points))
        elif isinstance(req, t.Bridge) and self._refs_pub is not None:
            self._refs_pub.publish(RefsSegCam(ref_altura=req.ref_altura, error_longitudinal=req.error_longitudinal,
                                              error_lateral=req.error_lateral, ref_heading=req.ref_heading,
                                              ref_rpm_motor=req.ref_rpm_motor))
        elif isinstance(req, t.LookAt):
            self.publish("pt_datos", DatosPT(latitud=req.lat, longitud=req.lon, altura=req.alt))
        elif isinstance(req, t.SetPanTilt):
            self.publish("pt_datos", DatosPT(ref_pan=req.pan, ref_tilt=req.tilt))
            with self.lock:
                self._pt_sent[task_id] = self.clock()
        return None

    def _abort(self) -> gri.TaskReply:
        """The manifest's ``abort`` task if it has one (empties both queues, stops motion; the task it replaces
        ends as aborted), then every other task ends as aborted; the abort task ends once done (the robot holds)."""
        abort_name = self.task_names.get("abort", "abort")
        abort_type = self.available.get(abort_name)
        problems = []
        abort_id = 0
        if abort_type is not None:
            reply = self._mri("task", mri.SetTask(name=abort_name, origin="gcs", replaced_as="aborted"))
            if reply is None or not reply.ok:
                problems.append(f"abort task: {'no reply' if reply is None else reply.reason}")
            elif isinstance(reply.data, mri.TaskList):
                abort_id = next((i.id for i in reply.data.active if i.task_type == abort_type), 0)
        with self.lock:
            others = sorted({i.task_type for i in self._live.values() if i.task_type != abort_type})
        for task_type in others:
            reply = self._mri("task", mri.EndTask(task_type=task_type, status="aborted", detail="abort"))
            if reply is None or not reply.ok:
                problems.append(f"end {task_type}: {'no reply' if reply is None else reply.reason}")
        if abort_id:
            self._mri("task", mri.EndTask(task_type=str(abort_type), task_id=abort_id, status="completed",
                                          detail="abort done: both waypoint queues empty, the robot holds"))
        if problems:
            return gri.TaskReply(accepted=False, reason="abort incomplete: " + "; ".join(problems))
        return gri.TaskReply(accepted=True)

    def _cancel(self, task_type: str) -> gri.TaskReply:
        with self.lock:
            known = task_type in set(self.available.values())
        if not known:
            return gri.TaskReply(accepted=False, reason=f"no task type {task_type!r} on robot {self.robot}")
        reply = self._mri("task", mri.EndTask(task_type=task_type, status="cancelled", detail="cancelled"))
        if reply is None or not reply.ok:
            reason = "Module Manager did not answer" if reply is None else reply.reason
            return gri.TaskReply(accepted=False, reason=reason, task_type=task_type)
        return gri.TaskReply(accepted=True, task_type=task_type)

    def _restart(self, module: str) -> gri.TaskReply:
        if module == self.module:
            # the manager stops this process to restart it, before its answer could reach the station: the station
            # is answered first, and the restart is asked for after (the worker's next job, once the reply is out)
            self._jobs.put(self._ask_own_restart)
            self.emit("module_restarted", detail=f"{module}: restarting itself, it answers again once up")
            return gri.TaskReply(accepted=True, reason=f"{module} restarts now: it answers again once up")
        with self.lock:
            ms = self._manager_state
            known = sorted(m.name for m in ms.modules) if ms is not None else []
        if known and module not in known:
            return gri.TaskReply(accepted=False, reason=f"restart {module}: no module {module!r} on robot "
                                                        f"{self.robot} (modules: {', '.join(known)})")
        # the manager answers once the module is up and linked, which can take longer than a station waits: asked
        # from a thread of its own (the worker stays free for an abort), answered as confirmed or as under way
        answered = threading.Event()
        outcome: dict[str, Any] = {"waiting": True}
        guard = threading.Lock()

        def ask() -> None:
            reply = self._restart_call(module)
            with guard:
                outcome["reply"] = reply
                if outcome["waiting"]:
                    answered.set()
                    return
            self._restart_outcome(module, reply)

        threading.Thread(target=ask, name=f"ral.restart.{module}", daemon=True).start()
        answered.wait(RESTART_REPLY_S)
        with guard:
            outcome["waiting"] = False
            if "reply" not in outcome:
                return gri.TaskReply(accepted=True, reason=(
                    f"restart {module} under way: not confirmed by the Module Manager within {RESTART_REPLY_S:g} s; "
                    "a module_restarted event (or an error) says how it ended"))
        reply = outcome["reply"]
        if reply is None or not reply.ok:
            reason = "Module Manager did not answer" if reply is None else reply.reason
            return gri.TaskReply(accepted=False, reason=f"restart {module}: {reason}")
        self.emit("module_restarted", detail=module)
        return gri.TaskReply(accepted=True)

    def _restart_call(self, module: str) -> mri.MriReply | None:
        """The manager's answer to a restart of ``module`` (None: none within ``RESTART_CONFIRM_S``)."""
        assert self.session is not None
        try:
            reply = mri.call(self.session, self.robot, "module", mri.ModuleCommand(module=module, action="restart"),
                             RESTART_CONFIRM_S)
        except mri.MriError:
            return None
        self._sync_list(reply.data)
        return reply

    def _restart_outcome(self, module: str, reply: mri.MriReply | None) -> None:
        """A restart the station was told was under way has ended: say how (event, or an error on the GRI)."""
        if reply is not None and reply.ok:
            self.emit("module_restarted", detail=f"{module} (confirmed after the reply)")
        elif reply is None:
            self._record_error(RalErrorCode.MRI_NO_REPLY, f"restart {module}: the Module Manager did not confirm it "
                                                          f"within {RESTART_CONFIRM_S:g} s")
        else:
            self._record_error(RalErrorCode.MRI_REFUSED, f"restart {module}: {reply.reason}")

    def _ask_own_restart(self) -> None:
        """Ask the manager to restart this RAL without waiting for its answer: the answer comes once the new RAL is
        up, and a query left pending here would hold this process's shutdown until it timed out."""
        assert self.session is not None
        self.session.get(mri.mri_key(self.robot, "module"), lambda _reply: None, timeout=self.cfg.mri_timeout_s,
                         payload=mri.encode(mri.ModuleCommand(module=self.module, action="restart")))

    def _run_failsafe(self, event: LinkEvent) -> None:
        request = self._failsafe_request(event.action)
        reply = self.handle(request, origin="failsafe")
        if not reply.accepted:
            self.emit("failsafe", detail=f"{event.action} refused ({reply.reason}); aborting instead")
            self._abort()

    def _failsafe_request(self, action: FailsafeAction | None) -> t.TaskParams:
        if action is FailsafeAction.LAND:
            return t.Land()
        if action is FailsafeAction.RETURN:
            with self.lock:  # RETURN_HEIGHT where it is, home at that height, then RETURN_ACTION (ral/tasks.py)
                plan = return_request(self.telemetry, self.home, self.limits, self.judge_cfg)
            if isinstance(plan, t.Goto):
                return plan
            self.emit("failsafe", detail=f"return: {plan}, holding instead")
        return t.Hold()

    # ------------------------------------------------------------ fleet allocation (issue 17, ral/fleet.py)

    def _fleet_start(self, session: zenoh.Session) -> None:
        cfg = FleetConfig(bid_window_s=self.cfg.fleet_bid_window_s,
                          reach_m=max(self.cfg.position_tolerance_m, 10.0),
                          reach_alt_m=max(self.cfg.altitude_tolerance_m, 5.0))
        self._fleet = FleetLink(self.robot, self.cfg.kind, self._fleet_own,
                                lambda job: self._jobs.put(lambda: self._fleet_fly(job)), cfg, clock=self.clock,
                                trust=self._fleet_trust())
        self._fleet.start(session)

    def _fleet_trust(self) -> FleetTrust | None:
        """Who may sign the fleet tasks this RAL adopts: None (any task) unless the robot is secured, i.e. the
        launch passed ``fleet_ca`` or the RAL's own bus is TLS."""
        tls = self.context.bus.tls
        ca = self.cfg.fleet_ca or (tls.root_ca if tls is not None else "")
        if not ca:
            return None
        signers = [x.strip() for x in self.cfg.fleet_signers.split(",") if x.strip()]
        trust = FleetTrust.from_files(ca, signers, self.cfg.fleet_crl or None)
        if signers:
            self.log.info("fleet tasks and world zone edits adopted only if signed by %s (certificate of %s)",
                          ", ".join(signers), ca)
        else:
            self.log.warning("secured bus but no fleet_signers: every fleet task and world zone edit is refused")
        return trust

    def _fleet_own(self) -> OwnState:
        with self.lock:
            kinds = available_kinds(self.available, self.task_names)
            speed = self.limits.cruise_speed or min(5.0, self.limits.max_speed)
            pack = (self.cfg.battery_empty_v, self.cfg.battery_full_v) if self.cfg.battery_full_v else None
            return own_state_of(self.telemetry, speed, can_do_from(self.cfg.fleet_can_do, kinds),
                                list(self._live.values()), available=not self.link.in_force, pack_v=pack)

    def _fleet_fly(self, job: Execute) -> None:
        goto = goto_of(job)
        with self.lock:
            grounded = self.telemetry is not None and self.telemetry.airborne is False
            self._then.clear()  # a new job replaces whatever an earlier one was waiting to fly
        first: t.TaskParams = goto
        if grounded:  # a path is flown from the air (ral/tasks.py: PATH_TASKS): the take-off, then the targets
            first = t.TakeOff(height=self.limits.takeoff_height_m or t.TakeOff().height)
        reply = self.handle(first, origin="fleet")
        if grounded and reply.accepted:
            with self.lock:
                self._then[reply.task_id] = goto
        self.log.info("fleet task %s round %d: %s %s%s", job.task.id, job.round, [x.id for x in job.targets],
                      "accepted" if reply.accepted else f"refused: {reply.reason}",
                      " (taking off first)" if grounded and reply.accepted else "")

    # ------------------------------------------------------------ fleet time and shared world (issue 17)
    # ral/sync_bus.py (clock offsets, synchronised start, formation) and ral/world_bus.py (the world model)

    def _world_sync_start(self) -> None:
        from ral.sync import SkewedClock
        from ral.sync_bus import SyncNode
        from ral.world_bus import WorldNode

        assert self.session is not None
        self.sync_clock = SkewedClock(self.cfg.sync_clock_offset_s, self.cfg.sync_clock_drift_ppm)
        self.world_node = WorldNode(self.session, self.robot, self.sync_clock, start_task=self.world_sync_handle,
                               point_at=self._point_at_target,
                               trust=self._fleet.gate.trust if self._fleet is not None else None)
        self.sync_node = SyncNode(self.session, self.robot, self.sync_clock, start_task=self.world_sync_handle,
                                   check_task=self._world_sync_check)

    def _world_sync_stop(self) -> None:
        for node in (getattr(self, "sync_node", None), getattr(self, "world_node", None)):
            if node is not None:
                node.close()

    def world_sync_handle(self, task: t.TaskParams, timeout_s: float = 30.0) -> gri.TaskReply:
        """A task from the fleet side (synchronised start, formation, target tracking), run on the worker thread
        in turn with the ground stations' tasks."""
        job = WorldSyncJob(lambda: self.handle(task))
        self._jobs.put(job)
        if not job.done.wait(timeout_s) or job.result is None:
            return gri.TaskReply(accepted=False, reason=f"the RAL did not run the {t.kind_of(task)} in {timeout_s:g} s")
        return job.result

    def _world_refusal(self, request: gri.TaskRequest) -> str | None:
        """What the shared world model forbids (no-fly zones, geofences), or None."""
        world = getattr(self, "world_node", None)
        if world is None:
            return None
        with self.lock:
            position = self.telemetry.position if self.telemetry else None
        return world.refusal(request, position)

    def _world_sync_check(self, task: t.TaskParams) -> str | None:
        """Why ``task`` would be refused now (world model, then admission), or None."""
        why = self._world_refusal(task)
        if why is not None:
            return why
        with self.lock:
            plan = admit(task, available=self.available, task_names=self.task_names, limits=self.limits,
                         cfg=self.judge_cfg, telemetry=self.telemetry, home=self.home)
        return plan.reason if isinstance(plan, Rejected) else None

    def _point_at_target(self, target: Any, task_id: int) -> bool:
        """A tracked world target moved: aim the running look_at task at it (False once that task ended)."""
        with self.lock:
            running = task_id in self._live
        if running:
            self.publish("pt_datos", DatosPT(latitud=target.lat, longitud=target.lon, altura=target.alt))
        return running


class WorldSyncJob:
    """A fleet-side task for the RAL's worker thread; ``done`` is set when ``result`` is there."""

    def __init__(self, run: Any) -> None:
        self._run = run
        self.result: gri.TaskReply | None = None
        self.done = threading.Event()

    def run(self) -> None:
        try:
            self.result = self._run()
        finally:
            self.done.set()


END_EVENTS = {
    "completed": "task_completed",
    "cancelled": "task_cancelled",
    "replaced": "task_replaced",
    "aborted": "aborted",
    "failed": "task_failed",
    "running": "task_accepted",
}


def p_max_speed() -> float:
    """Without a robot .conf, the protocol's ceiling is the only speed limit known."""
    return MAX_SPEED_LIMIT


def main(argv: list[str] | None = None) -> int:
    return Ral.main(argv)
