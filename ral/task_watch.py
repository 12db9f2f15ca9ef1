"""The RAL's watch over running tasks: the manager's task book followed (GRI events derived from its lists), each
movement task judged against telemetry (complete, stalled), loss of control and module errors failing what they
affect. A mixin of :class:`ral.module.Ral`: its state lives there; the main loop's tick calls it."""

from __future__ import annotations

from typing import Any

from bbcs import SlotError
from bbcs.contracts import mri
from bbcs.contracts import tasks as t
from bbcs.contracts.error_codes import RalErrorCode, error_name
from bbcs.contracts.pan_tilt import DatosPT
from bbcs.contracts.robot import RobotTelemetry
from ral import faults as telemetry_faults
from ral.config import (
    END_EVENTS,
    HARMLESS_CODES,
)
from ral.failsafe import LinkEvent
from ral.health import HealthFault
from ral.tasks import (
    Progress,
    after_completed,
    judge,
    pan_tilt_check,
)


class TaskWatch:
    """The RAL's watch over running tasks (a mixin of the RAL module)."""

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
            withdraw = self._pt_on_slot is not None and self._pt_on_slot in self._finished
            if withdraw:
                self._pt_on_slot = None
        if withdraw:
            try:
                self.output("pt_datos").withdraw()
            except SlotError:  # stopping: the slot (and its value) go with the module
                pass
        for kind, info, detail in out:
            self.emit(kind, task_id=info.id, task_type=info.task_type, detail=detail)

    def _put_pt_datos(self, task_id: int, datum: DatosPT) -> None:
        """Put ``datum`` on ``pt_datos`` for task ``task_id``: the one place the RAL does, so the value is withdrawn
        when that task ends (``_sync``)."""
        with self.lock:
            self._pt_on_slot = task_id
        self.publish("pt_datos", datum)

    def _sync_list(self, data: Any) -> None:
        if isinstance(data, mri.TaskList):
            with self.lock:
                self.available = dict(data.available)
            self._sync(data.epoch, data.version, data.active, data.ended)

    def _fold_telemetry(self, tel: RobotTelemetry, now: float) -> None:
        """Judge every running task against new telemetry; a verdict goes to the manager as an EndTask."""
        with self.lock:
            self.telemetry = tel
            if tel.airborne is False and tel.position is not None:
                self.home = tel.position
            verdicts = []
            resend: list[tuple[int, t.TaskParams | None]] = []
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
                        resend.append((task_id, info.params))
            for task_id in set(self._pt_sent) - set(self._live):
                del self._pt_sent[task_id]
            faults = self.health.update(tel, list(self._live.values()), self.home)
        for task_id, req in resend:
            assert isinstance(req, t.SetPanTilt)
            self.pt_resends += 1
            self.log.info("pan & tilt at %s/%s, not at the task's %g/%g: its angles sent again", tel.pan_deg,
                          tel.tilt_deg, req.pan, req.tilt)
            self._put_pt_datos(task_id, DatosPT(ref_pan=req.pan, ref_tilt=req.tilt))
        for info, status, detail in verdicts:
            self._jobs.put(mri.EndTask(task_type=info.task_type, task_id=info.id, status=status, detail=detail))
        for fault in faults:
            self._health_fault(fault)

    def _health_fault(self, fault: HealthFault) -> None:
        """A loss of control in the robot's own telemetry (ral/health.py): an error with its severity on the GRI
        (published now), the running movement tasks failed with the reason, the robot's health action run as a
        failsafe."""
        code = RalErrorCode.LOSS_OF_CONTROL
        now = self.clock()
        with self.lock:
            self._error_log.append(mri.ErrorEvent(module="ral", code=int(code), name=code.name, stamp=now,
                                                  detail=fault.detail, severity=fault.severity))
        # on the GRI at once, not at the next tick: the judge runs on the loop as the telemetry comes in, and the
        # tick after it is a whole step later in lockstep (the uQuad's 604 once reached the GRI 1.09 s after the
        # truth showed the tumble, where the budget is 1 s)
        self._next_state = now + self.cfg.state_period_s
        self._publish_state(now)
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
                if info.task_type in serves.get(e.module, set()) and e.stamp >= info.started \
                        and not telemetry_faults.answers_fault(info, e.code):
                    name = e.name or error_name(e.module, e.code)  # the manager's records carry the bare code
                    detail = mri.module_error_detail(e.module, e.code, name)
                    self._jobs.put(mri.EndTask(task_type=info.task_type, task_id=info.id, status="failed",
                                               detail=detail))
                    break

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

