"""The RAL process (``python -m ral``): serves the GRI, turns tasks into MRI requests to the manager.

It is a bbcs :class:`~bbcs.module.Module` named ``ral`` so the manager launches and supervises it like any
other module. Its own output slots carry the data a task needs (the manifest's task map routes the robot's
modules to them): ``path`` (waypoints), ``speed``, ``pt_datos`` (pan & tilt angles or target point).

One worker thread handles task queries and failsafe actions in arrival order, so a task is admitted, sent to
the manager and recorded before the next one is looked at. The main loop's tick folds in the manager's robot
state (completion detection), advances the link-loss failsafe and publishes the GRI state.
"""

from __future__ import annotations

import enum
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
from bbcs.module import Module
from bbcs.slots import Direction, Kind, OutputSlot, Publisher, Safety, SlotSpec
from module_manager import mri
from modules.pan_tilt.structs import DatosPT
from modules.path_follower.structs import DatoPuntoSegCam, DatosSegCam, SpeedSegCam
from ral import gri
from ral.failsafe import FailsafeAction, FailsafeConfig, LinkEvent, LinkMonitor
from ral.tasks import Plan, QueueConfig, Rejected, TaskQueue

MAX_ERRORS = 20
MANAGER_STALE_S = 3.0
TASKS_REFRESH_S = 1.0


class RalErrorCode(enum.IntEnum):
    MRI_NO_REPLY = 601
    """The Module Manager did not answer an MRI request."""
    MRI_REFUSED = 602
    """The Module Manager refused a request the RAL had admitted."""


class RalError(msgspec.Struct, frozen=True, kw_only=True):
    """The RAL's ERROR slot."""

    error_ral: int


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
    return_height_m: float = 10.0
    """The ``return`` failsafe flies home at least this high above the take-off point."""
    mri_timeout_s: float = mri.REPLY_TIMEOUT_S
    """Must exceed the manager's ack wait (``mri.MANAGER_ACK_S``), else a task can be applied after being refused."""
    state_period_s: float = 0.2
    kind: str = ""
    """Robot kind shown in the GRI state when the manager's state has none."""

    @classmethod
    def from_params(cls, params: dict[str, str]) -> tuple[RalConfig, dict[str, str]]:
        plain = {k: v for k, v in params.items() if not k.startswith("task.")}
        names = {k.removeprefix("task."): v for k, v in params.items() if k.startswith("task.")}
        unknown = set(plain) - set(cls.__struct_fields__)
        if unknown:
            raise ValueError(
                f"unknown RAL parameter(s) {sorted(unknown)}; known: {', '.join(cls.__struct_fields__)}"
            )
        try:
            cfg = msgspec.convert(plain, cls, strict=False)
        except msgspec.ValidationError as exc:
            raise ValueError(f"bad RAL parameter: {exc}") from exc
        if cfg.mri_timeout_s <= mri.MANAGER_ACK_S:
            raise ValueError(
                f"bad RAL parameter: mri_timeout_s = {cfg.mri_timeout_s:g} must exceed the manager's ack wait "
                f"({mri.MANAGER_ACK_S:g} s), or a task could be applied after the ground station was told it failed"
            )
        return cfg, names


class Ral(Module):
    name: ClassVar[str] = "ral"
    slots = (
        OutputSlot("path", DatosSegCam, kind=Kind.STREAM),
        OutputSlot("speed", SpeedSegCam),
        OutputSlot("pt_datos", DatosPT),
        OutputSlot("error", RalError),
    )
    error_slot = "error"
    tick_period = 0.05

    def __init__(self, context: ModuleContext, clock: Any = time.time) -> None:
        super().__init__(context)
        self.cfg, names = RalConfig.from_params(context.params)
        self.clock = clock
        self.queue = TaskQueue(
            context.robot,
            QueueConfig(
                position_tolerance_m=self.cfg.position_tolerance_m,
                altitude_tolerance_m=self.cfg.altitude_tolerance_m,
                settle_s=self.cfg.settle_s,
                max_range_m=self.cfg.max_range_m,
            ),
            task_names=names,
        )
        self.link = LinkMonitor(
            FailsafeConfig(
                loss_timeout_s=self.cfg.failsafe_timeout_s,
                heartbeat_timeout_s=self.cfg.heartbeat_timeout_s,
                regain_s=self.cfg.regain_s,
                action=self.cfg.failsafe_action,
            )
        )
        self._jobs: queue.Queue[Any] = queue.Queue()
        self._bus_lock = threading.Lock()
        self._manager_state: mri.RobotState | None = None
        self._manager_seen = 0.0
        self._manager_new = False
        self._manager_up = False
        self._error_log: deque[gri.ErrorRecord] = deque(maxlen=MAX_ERRORS)
        self._ral_entities: list[Any] = []
        self._worker: threading.Thread | None = None
        self._state_pub: Publisher[gri.GriState] | None = None
        self._event_pub: Publisher[gri.GriEvent] | None = None
        self._next_state = 0.0
        self._tasks_fetched = 0.0

    # ------------------------------------------------------------ bus

    def on_start(self) -> None:
        s = self.session
        assert s is not None
        self._state_pub = Publisher(
            s,
            gri.state_key(self.robot),
            SlotSpec("state", gri.GriState, Direction.OUT, Kind.STATE, Safety.SAFE),
        )
        self._event_pub = Publisher(
            s,
            gri.events_key(self.robot),
            SlotSpec("events", gri.GriEvent, Direction.OUT, Kind.STREAM, Safety.SAFE),
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
            s.declare_queryable(gri.task_key(self.robot), self._jobs.put),
            wire.declare_service_schemas(s, keys.ral_key(self.robot), lambda: {
                gri.state_key(self.robot): gri.GriState, gri.events_key(self.robot): gri.GriEvent,
                gri.task_key(self.robot): {"request": gri.TaskRequest, "reply": gri.TaskReply}}),
        ]
        self._worker = threading.Thread(target=self._work, name="ral.tasks", daemon=True)
        self._worker.start()
        self._jobs.put("refresh_tasks")

    def on_stop(self) -> None:
        self._jobs.put(None)
        if self._worker is not None:
            self._worker.join(5.0)
        for entity in reversed(self._ral_entities):
            entity.undeclare()
        self._ral_entities.clear()
        for pub in (self._state_pub, self._event_pub):
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

    def _on_gcs_token(self, sample: zenoh.Sample) -> None:
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        with self.lock:
            self.link.token(name, sample.kind == zenoh.SampleKind.PUT)

    def _on_gcs_heartbeat(self, sample: zenoh.Sample) -> None:
        try:
            gri.decode_heartbeat(sample.payload.to_bytes())
        except msgspec.MsgspecError:
            return
        with self.lock:
            self.link.heartbeat(self.clock())

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

    def _emit_end(self, info: gri.TaskInfo) -> None:
        kind = {
            "completed": "task_completed",
            "cancelled": "task_cancelled",
            "replaced": "task_replaced",
            "aborted": "aborted",
            "failed": "task_failed",
        }[info.status]
        self.emit(kind, task_id=info.id, task_type=info.task_type, detail=info.detail or info.kind)

    # ------------------------------------------------------------ main loop

    def on_tick(self) -> None:
        now = self.clock()
        if self._manager_new and self._manager_state is not None:
            self._manager_new = False
            if self._manager_state.telemetry is not None:
                for info in self.queue.on_telemetry(self._manager_state.telemetry, now):
                    self._emit_end(info)
        up = self._manager_state is not None and now - self._manager_seen <= MANAGER_STALE_S
        if up != self._manager_up:
            self._manager_up = up
            self.emit("manager_back" if up else "manager_lost")
            if up:
                self._jobs.put("refresh_tasks")
        if not self.queue.available and now - self._tasks_fetched >= TASKS_REFRESH_S:
            self._tasks_fetched = now
            self._jobs.put("refresh_tasks")
        for event in self.link.update(now):
            self.emit(event.kind, detail=event.detail)
            if event.action is not None:
                self._jobs.put(event)
        if now >= self._next_state:
            self._next_state = now + self.cfg.state_period_s
            self._publish_state(now)

    def _publish_state(self, now: float) -> None:
        ms = self._manager_state
        tel = ms.telemetry if ms else None
        errors = [
            gri.ErrorRecord(source=e.module, code=e.code, stamp=e.stamp) for e in (ms.errors if ms else [])
        ]
        errors = sorted([*errors, *self._error_log], key=lambda e: e.stamp)[-MAX_ERRORS:]
        state = gri.GriState(
            robot=self.robot,
            kind=(ms.kind if ms and ms.kind else self.cfg.kind),
            stamp=now,
            position=tel.position if tel else None,
            attitude=tel.attitude if tel else None,
            velocity=tel.velocity if tel else None,
            heading_deg=tel.heading_deg if tel else None,
            mode=tel.mode if tel else None,
            mode_name=tel.mode_name if tel else "",
            airborne=tel.airborne if tel else None,
            waypoints_queued=tel.waypoints_queued if tel else None,
            pan_deg=tel.pan_deg if tel else None,
            tilt_deg=tel.tilt_deg if tel else None,
            home=self.queue.home,
            tasks=self.queue.tasks(),
            available=dict(self.queue.available),
            modules=[
                gri.ModuleHealth(
                    name=m.name,
                    state=m.state,
                    restarts=m.restarts,
                    last_exit=m.last_exit,
                    reason=m.reason,
                    last_error=m.last_error,
                    routes=dict(m.routes),
                )
                for m in (ms.modules if ms else [])
            ],
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
            try:
                if job == "refresh_tasks":
                    self._refresh_tasks()
                elif isinstance(job, LinkEvent):
                    self._run_failsafe(job)
                else:
                    self._answer(job)
            except Exception:
                self.log.exception("RAL job failed")

    def _mri(self, verb: str, request: msgspec.Struct) -> mri.MriReply | None:
        assert self.session is not None
        try:
            return mri.call(self.session, self.robot, verb, request, self.cfg.mri_timeout_s)
        except mri.MriError as exc:
            self._record_error(RalErrorCode.MRI_NO_REPLY, str(exc))
            return None

    def _record_error(self, code: int, detail: str) -> None:
        with self.lock:
            self._error_log.append(
                gri.ErrorRecord(source="ral", code=int(code), stamp=self.clock(), detail=detail)
            )
            self.report_error(int(code), detail)

    def _refresh_tasks(self) -> None:
        reply = self._mri("tasks", mri.ListTasks())
        if reply is not None and reply.ok and isinstance(reply.data, mri.TaskList):
            with self.lock:
                self.queue.available = dict(reply.data.available)

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

    def handle(self, request: gri.TaskRequest, origin: str = "gcs") -> gri.TaskReply:
        """Admit, send to the manager, record; the reply says accepted or why not."""
        if isinstance(request, gri.Abort):
            return self._abort()
        if isinstance(request, gri.Cancel):
            return self._cancel(request.task_type)
        if not self.queue.available:
            self._refresh_tasks()
        with self.lock:
            plan = self.queue.admit(request)
        if isinstance(plan, Rejected):
            self.emit("task_rejected", task_type="", detail=f"{gri.kind_of(request)}: {plan.reason}")
            return gri.TaskReply(accepted=False, reason=plan.reason)
        reply = self._mri("task", mri.SetTask(name=plan.name, params=plan.params))
        if reply is None or not reply.ok:
            reason = (
                "Module Manager did not answer"
                if reply is None
                else f"Module Manager refused task {plan.name!r}: {reply.reason}"
            )
            if reply is not None:
                self._record_error(RalErrorCode.MRI_REFUSED, reason)
            self.emit("task_rejected", task_type=plan.task_type, detail=reason)
            return gri.TaskReply(accepted=False, reason=reason, task_type=plan.task_type)
        with self.lock:
            info, replaced = self.queue.start(plan, self.clock(), origin)
        self._publish_data(plan)
        if replaced is not None:
            self._emit_end(replaced)
        self.emit(
            "task_accepted",
            task_id=info.id,
            task_type=info.task_type,
            detail=f"{info.kind} as {info.name}" + (" (failsafe)" if origin == "failsafe" else ""),
        )
        return gri.TaskReply(accepted=True, task_id=info.id, task_type=info.task_type)

    def _publish_data(self, plan: Plan) -> None:
        req = plan.request
        if isinstance(req, gri.Goto | gri.FollowPath):
            if req.speed is not None:
                self.publish("speed", SpeedSegCam(speed=req.speed))
            points = [DatoPuntoSegCam(latitud=w.lat, longitud=w.lon, altura=w.alt) for w in req.waypoints]
            self.publish("path", DatosSegCam(n_points=len(points), puntos=points))
        elif isinstance(req, gri.LookAt):
            self.publish("pt_datos", DatosPT(latitud=req.lat, longitud=req.lon, altura=req.alt))
        elif isinstance(req, gri.SetPanTilt):
            self.publish("pt_datos", DatosPT(ref_pan=req.pan, ref_tilt=req.tilt))

    def _abort(self) -> gri.TaskReply:
        """The manifest's ``abort`` task if it has one (stops motion at once), then end the rest."""
        abort_name = self.queue.name_for("abort")
        abort_type = self.queue.available.get(abort_name)
        problems = []
        if abort_type is not None:
            reply = self._mri("task", mri.SetTask(name=abort_name))
            if reply is None or not reply.ok:
                problems.append(f"abort task: {'no reply' if reply is None else reply.reason}")
        with self.lock:
            active = [t for t in sorted(self.queue.current) if t != abort_type]
        for task_type in active:
            reply = self._mri("task", mri.EndTask(task_type=task_type))
            if reply is None or not reply.ok:
                problems.append(f"end {task_type}: {'no reply' if reply is None else reply.reason}")
        with self.lock:
            ended = self.queue.abort(self.clock())
        for info in ended:
            self._emit_end(info)
        if problems:
            return gri.TaskReply(accepted=False, reason="abort incomplete: " + "; ".join(problems))
        return gri.TaskReply(accepted=True)

    def _cancel(self, task_type: str) -> gri.TaskReply:
        with self.lock:
            known = task_type in self.queue.current or task_type in set(self.queue.available.values())
        if not known:
            return gri.TaskReply(accepted=False, reason=f"no task type {task_type!r} on robot {self.robot}")
        reply = self._mri("task", mri.EndTask(task_type=task_type))
        if reply is None or not reply.ok:
            reason = "Module Manager did not answer" if reply is None else reply.reason
            return gri.TaskReply(accepted=False, reason=reason, task_type=task_type)
        with self.lock:
            info = self.queue.cancel(task_type, self.clock())
        if info is not None:
            self._emit_end(info)
        return gri.TaskReply(accepted=True, task_type=task_type, task_id=info.id if info else 0)

    def _run_failsafe(self, event: LinkEvent) -> None:
        request = self._failsafe_request(event.action)
        reply = self.handle(request, origin="failsafe")
        if not reply.accepted:
            self.emit("failsafe", detail=f"{event.action} refused ({reply.reason}); aborting instead")
            self._abort()

    def _failsafe_request(self, action: FailsafeAction | None) -> gri.Task:
        if action is FailsafeAction.LAND:
            return gri.Land()
        if action is FailsafeAction.RETURN:
            with self.lock:
                home = self.queue.home
                tel = self.queue.telemetry
            if home is not None:
                alt = max(
                    home.alt + self.cfg.return_height_m,
                    tel.position.alt if tel and tel.position else home.alt,
                )
                return gri.Goto(waypoints=[gri.Waypoint(lat=home.lat, lon=home.lon, alt=alt)])
            self.emit("failsafe", detail="return: take-off point unknown, holding instead")
        return gri.Hold()


def main(argv: list[str] | None = None) -> int:
    return Ral.main(argv)
