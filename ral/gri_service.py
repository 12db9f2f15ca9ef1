"""The GRI service: a ground station's task requests admitted (ral/tasks.py), sent to the Module Manager as MRI
requests with their data (carried inside the task's modes where the manifest allows, else published once the
manager accepted them); abort, cancel, module restarts; the ground-station
link and the failsafe it runs. A mixin of :class:`ral.module.Ral`: its state lives there; one worker thread
serves the requests in arrival order."""

from __future__ import annotations

import threading
from typing import Any

import msgspec
import zenoh
import zenoh.ext

from bbcs import (
    Direction,
    Kind,
    Publisher,
    Safety,
    SlotSpec,
    wire,
)
from bbcs.contracts import gri, mri
from bbcs.contracts import tasks as t
from bbcs.contracts.error_codes import RalErrorCode
from bbcs.contracts.pan_tilt import DatosPT
from bbcs.contracts.path_follower import (
    DatoPuntoSegCam,
    DatosSegCam,
    HeadingSegCam,
    RefsSegCam,
    SpeedSegCam,
)
from ral.config import (
    RESTART_CONFIRM_S,
    RESTART_REPLY_S,
)
from ral.failsafe import FailsafeAction, LinkEvent
from ral.tasks import (
    Plan,
    Rejected,
    admit,
    return_request,
)

EVENTS_REPLAY = 256
"""GRI events the RAL keeps for a ground station that missed them while its link to the robot was cut: the
ground station's subscriber (``Gcs.events``) asks for them once the link is back (docs/gcs.md)."""


def events_publisher(session: zenoh.Session, robot: str) -> Publisher[gri.GriEvent]:
    """The robot's GRI event stream: a safe stream whose last ``EVENTS_REPLAY`` events are kept for replay."""
    return Publisher(session, gri.events_key(robot),
                     SlotSpec("events", gri.GriEvent, Direction.OUT, Kind.STREAM, Safety.SAFE), replay=EVENTS_REPLAY)


def task_data(req: t.TaskParams) -> dict[str, msgspec.Struct]:
    """A task's data, by the RAL output slot each is published on (what the manager may carry inside the task's
    mode instead: ``SetTask.data``). In the order they go out when published: speed, heading, path, angles."""
    out: dict[str, msgspec.Struct] = {}
    if isinstance(req, t.Goto | t.FollowPath | t.FollowVisionPath | t.Survey | t.Orbit):
        assert req.speed is not None, "admission fills in the cruise speed"
        out["speed"] = SpeedSegCam(speed=req.speed)
    if isinstance(req, t.FollowPath) and req.heading is not None:
        out["heading"] = HeadingSegCam(heading=req.heading)
    if isinstance(req, t.Goto | t.FollowPath):
        out["path"] = DatosSegCam(n_points=len(req.waypoints), puntos=[
            DatoPuntoSegCam(latitud=w.lat, longitud=w.lon, altura=w.alt) for w in req.waypoints])
    elif isinstance(req, t.LookAt):
        out["pt_datos"] = DatosPT(latitud=req.lat, longitud=req.lon, altura=req.alt)
    elif isinstance(req, t.SetPanTilt):
        out["pt_datos"] = DatosPT(ref_pan=req.pan, ref_tilt=req.tilt)
    return out


class GriService:
    """The GRI service (a mixin of the RAL module)."""

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
        why = self._world_refusal(request) or self._unwired(request)
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
        if isinstance(plan.params, t.Survey | t.Orbit):  # a plan the generator refuses must not replace a task
            why = self._request_path(plan.params, 0, check_only=True)
            if why is not None:
                self.emit("task_rejected", task_type=plan.task_type, detail=why)
                return gri.TaskReply(accepted=False, reason=why, task_type=plan.task_type)
        data = task_data(plan.params)
        reply = self._mri("task", mri.SetTask(name=plan.name, params=plan.params, origin=origin, data={
            slot: msgspec.Raw(msgspec.msgpack.encode(value)) for slot, value in data.items()}))
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
        problem = self._publish_data(plan, task_id, {k: v for k, v in data.items() if k not in reply.carried})
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

    def _unwired(self, request: gri.TaskRequest) -> str | None:
        """Why a task cannot be served because the manifest wires no module for its data (before anything starts)."""
        if isinstance(request, t.Survey | t.Orbit) and self._traj_pub is None:
            return (f"{t.kind_of(request)}: this robot has no path planner (the RAL's manifest parameter planner is "
                    "empty)")
        if isinstance(request, t.Bridge) and self._refs_pub is None:
            return ("bridge: no module takes the references on this robot (the RAL's manifest parameter refs_to is "
                    "empty)")
        return None

    def _publish_data(self, plan: Plan, task_id: int, data: dict[str, msgspec.Struct]) -> str | None:
        """After the manager's reply: the task's ``data`` its modes did not carry, on the RAL's slots (the module
        answered the task's mode, so they are handled under it), then what follows a task's start (a survey's
        path request, a bridge's references). A path's speed goes first and is acknowledged before the path
        (docs/gcs.md, "Speed before path"). Returns None, or why the task's data could not go out."""
        req = plan.params
        self.publish("task", t.TaskData(task_id=task_id, params=req))
        speed = data.get("speed")
        if isinstance(speed, SpeedSegCam):
            problem = self._send_speed(speed.speed)
            if problem is not None:
                return problem
        if isinstance(req, t.Survey | t.Orbit):
            return self._request_path(req, task_id)
        for slot in ("heading", "path"):
            if slot in data:
                self.publish(slot, data[slot])
        pt = data.get("pt_datos")
        if isinstance(pt, DatosPT):
            self._put_pt_datos(task_id, pt)
        if isinstance(req, t.Bridge) and self._refs_pub is not None:
            self._refs_pub.publish(RefsSegCam(ref_altura=req.ref_altitude, error_longitudinal=req.error_longitudinal,
                                              error_lateral=req.error_lateral, ref_heading=req.ref_heading,
                                              ref_rpm_motor=req.ref_rpm_motor))
        if isinstance(req, t.SetPanTilt):
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

