"""The Module Manager's request interface (MRI): one thread serves ``cromat/<robot>/@manager/<verb>`` queries.

A mixin of :class:`module_manager.manager.Manager` (its state and its route control), kept apart because it is one
job: decode a request (decode is validation), answer it from the task book, the module records and the parameter
desk, and reply on the verb's own key. Served by a thread of its own, so a request that waits for a module's
acknowledgement never blocks the Zenoh callbacks that bring it.
"""

from __future__ import annotations

from typing import Any

import msgspec
import zenoh

from bbcs import wire
from bbcs.codec import resolve_type
from bbcs.contracts import mri
from module_manager.supervision import Phase
from module_manager.task_data import carry, kept


class MriService:
    """The MRI of :class:`~module_manager.manager.Manager` (a mixin: the manager holds the state)."""

    lock: Any
    modules: Any
    m: Any
    mode_fields: dict[str, frozenset[str]]
    mode_streams: dict[str, frozenset[str]]
    carried_from: dict[str, dict[str, int]]

    def _serve_mri(self, queryable: Any) -> None:
        try:
            for query in queryable:
                self._mri_busy = True
                try:
                    reply = self.handle_mri(str(query.key_expr).rsplit("/", 1)[-1],
                                            query.payload.to_bytes() if query.payload is not None else b"")
                except Exception as exc:  # a bug must still produce an answer, not a silent timeout
                    reply = mri.MriReply(ok=False, reason=f"internal error: {type(exc).__name__}: {exc}")
                try:
                    wire.reply(query, query.key_expr, reply)
                except Exception:  # the querier gave up or the session is closing
                    pass
                finally:
                    query.drop()  # finalise now: a consolidating querier waits for the end of the query
                    self._mri_busy = False
        except zenoh.ZError:
            pass

    def handle_mri(self, verb: str, payload: bytes) -> mri.MriReply:
        """Answer one MRI request: every request gets a reply, ok or with the reason it was refused."""
        try:
            req = mri.decode_request(payload)
        except msgspec.MsgspecError as exc:
            return mri.MriReply(ok=False, reason=f"unreadable {verb} request: {exc}")
        expected = {"modules": (mri.ListModules,), "routes": (mri.ListRoutes,), "route": (mri.SwapRoute,),
                    "module": (mri.ModuleCommand,), "task": (mri.SetTask, mri.EndTask), "tasks": (mri.ListTasks,),
                    "mode": (mri.SetModuleMode,), "param": (mri.ListParams, mri.GetParam, mri.SetParam)}.get(verb)
        if expected is None:
            return mri.MriReply(ok=False, reason=f"unknown MRI verb {verb!r}; known: {', '.join(mri.VERBS)}")
        if not isinstance(req, expected):
            return mri.MriReply(ok=False, reason=f"verb {verb!r} takes {' or '.join(t.__name__ for t in expected)}, "
                                                 f"not {type(req).__name__}")
        if isinstance(req, mri.ListModules):
            with self.lock:
                return mri.MriReply(ok=True, data=mri.ModuleList(
                    robot=self.m.robot, modules=[self.module_status(n) for n in self.modules]))
        if isinstance(req, mri.ListRoutes):
            return mri.MriReply(ok=True, data=self.route_list())
        if isinstance(req, mri.SwapRoute):
            ok, why = self.apply_routes({(req.module, req.input): req.slot})
            if ok:
                self._resend_carried(req.module, req.input, req.slot)
            return mri.MriReply(ok=ok, reason=why, data=self.route_list())
        if isinstance(req, mri.ModuleCommand):
            return self.module_command(req)
        if isinstance(req, mri.ListTasks):
            return mri.MriReply(ok=True, data=self.task_list())
        if isinstance(req, mri.SetTask | mri.EndTask):
            return self.task_request(req)
        if isinstance(req, mri.ListParams | mri.GetParam | mri.SetParam):
            return self.params.handle(req, {n: m.info for n, m in self.modules.items()}, self.expand,
                                      self._not_up, self.session, self._touch_locked, self.out)
        assert isinstance(req, mri.SetModuleMode)
        slot = next((n for n, m in self.m.modes.items() if m.module == req.module), None)
        if slot is None:
            return mri.MriReply(ok=False, reason=f"no mode slot drives module {req.module!r}")
        try:
            ok, why, code = self.publish_mode(slot, req.mode)
        except msgspec.ValidationError as exc:
            return mri.MriReply(ok=False, reason=f"mode for {req.module!r} refused: {exc}")
        return mri.MriReply(ok=ok, reason=why, code=code)

    def _not_up(self, name: str) -> str | None:
        with self.lock:
            sup = self.modules[name].sup
            return None if sup.phase is Phase.UP else sup.state

    def _touch_locked(self) -> None:
        with self.lock:
            self._touch()

    def route_list(self) -> mri.RouteList:
        with self.lock:
            return mri.RouteList(routes={n: dict(m.routes) for n, m in self.modules.items() if m.routes},
                                 slots={k: f"{r.module}/{r.slot}" for k, r in self.m.slot_table.slots.items()})

    def task_list(self) -> mri.TaskList:
        with self.lock:
            return mri.TaskList(active=self.tasks.active(), ended=list(self.tasks.ended),
                                available={n: t.type for n, t in self.m.tasks.items()}, version=self.tasks.version,
                                epoch=self.epoch)

    def module_command(self, req: mri.ModuleCommand) -> mri.MriReply:
        with self.lock:
            mod = self.modules.get(req.module)
            if mod is None:
                return mri.MriReply(ok=False, reason=f"no module {req.module!r} in robot {self.m.robot!r}")
            now = self.clock()
            if req.action == "stop":
                self._perform(mod, mod.sup.stop(now))
                done = (Phase.STOPPED,)
            elif req.action == "start":
                mod.sup.start(now)
                done = (Phase.UP, Phase.FAILED)
            else:
                self._perform(mod, mod.sup.restart(now))
                done = (Phase.UP, Phase.FAILED)
            self._touch()
            end = now + mod.info.policy.start_timeout_s + self.m.stop_grace_s
            while mod.sup.phase not in done and self.clock() < end and not self.stop_event.is_set():
                self.changed.wait(0.05)
            status = self.module_status(req.module)
            ok = mod.sup.phase in done and mod.sup.phase is not Phase.FAILED
        return mri.MriReply(ok=ok, reason="" if ok else f"module {req.module} is {status.state}: {status.reason}",
                            data=status)

    def task_request(self, req: mri.SetTask | mri.EndTask) -> mri.MriReply:
        """Start or end a task in the task book (the only one), then apply its routes and modes (a started task's
        data inside its modes where they can be: module_manager/task_data.py)."""
        carried: list[str] = []
        with self.lock:
            routes = {(n, i): v for n, m in self.modules.items() for i, v in m.routes.items()}
            modes = dict(self.modes)
            now = self.stamp()
            if isinstance(req, mri.SetTask):
                if req.name not in self.m.tasks:
                    known = ", ".join(self.m.tasks) or "none"
                    return mri.MriReply(ok=False, reason=f"unknown task {req.name!r} (tasks: {known})")
                for name in sorted(self.task_uses.get(req.name, set())):
                    sup = self.modules[name].sup
                    if sup.phase is not Phase.UP:
                        why = f": {sup.reason}" if sup.reason else ""
                        return mri.MriReply(ok=False, reason=f"task {req.name!r} needs module {name}, which is "
                                                             f"{sup.state}{why}", data=self.task_list())
                data = self._task_data(req)
                if isinstance(data, str):
                    return mri.MriReply(ok=False, reason=data, data=self.task_list())
                changes = self.tasks.start(req.name, req.params, now, routes, modes, req.origin, req.replaced_as)
                task_type = self.m.tasks[req.name].type
                inside = carry(data, self.m.tasks[req.name].modes, {n: m.module for n, m in self.m.modes.items()},
                               self.mode_fields, {**routes, **changes.routes}) if data else None
                for slot in changes.modes:
                    self.carried_from.pop(slot, None)
                if inside:
                    changes = self.tasks.carry(task_type, changes, inside)
                    carried = list(req.data)
                    after = {**routes, **changes.routes}
                    for slot, fields in inside.items():
                        module = self.m.modes[slot].module
                        self.carried_from[slot] = {f: after[(module, f)] for f in fields}
            else:
                if req.task_type not in self.m.task_types:
                    return mri.MriReply(ok=False, reason=f"unknown task type {req.task_type!r}")
                running = self.tasks.running(req.task_type)
                if running is None or (req.task_id and running.id != req.task_id):
                    what = f"task {req.task_id}" if req.task_id else f"{req.task_type} task"
                    return mri.MriReply(ok=False, reason=f"no {what} is running", data=self.task_list())
                changes = self.tasks.end(req.task_type, now, req.status, req.detail)
            self._touch()
        ok, why, code = self.apply_changes(changes, ending=isinstance(req, mri.EndTask))
        if not ok and isinstance(req, mri.SetTask):
            with self.lock:  # refused: the task never ran; what it changed is put back
                task = self.tasks.running(self.m.tasks[req.name].type)
                undo = self.tasks.end(task.task_type, self.stamp(), "failed", why) if task is not None else None
                self._touch()
            if undo is not None:
                self.apply_changes(undo, ending=True)
        return mri.MriReply(ok=ok, reason=why, code=code, data=self.task_list(), carried=carried if ok else [])

    def _resend_carried(self, module: str, input_slot: str, number: int) -> None:
        """``module``'s ``input_slot`` was routed back to the slot whose datum its task's mode carries: that datum
        lives in the mode, not in the source slot (module_manager/task_data.py), so the mode is sent again with
        it, as delivered (without stream data): the module acts on the task's data again, as a re-read would. Only
        while the mode's value carries that datum: once the task has ended, its slot holds another value."""
        with self.lock:
            slot = next((n for n, m in self.m.modes.items() if m.module == module
                         and self.carried_from.get(n, {}).get(input_slot) == number), None)
            value = self.tasks.shown(slot) if slot is not None else None  # the running task's, never an ended one's
        if slot is not None and value is not None and value.get(input_slot) is not None:
            origins = self.carried_from.get(slot, {})
            self.publish_mode(slot, kept(value, self.mode_streams.get(slot, frozenset())) or {})
            with self.lock:
                self.carried_from[slot] = origins

    def _task_data(self, req: mri.SetTask) -> dict[int, Any] | str:
        """``req.data`` by slot number, each decoded as its slot's struct (decode is validation), as builtins for a
        mode's fields; ``{}`` when one of them has no slot of the sender's in the slot table (all or none: the sender
        publishes them all). Why the task is refused, if a datum does not decode."""
        numbers = {(ref.module, ref.slot): n for n, ref in self.m.slot_table.slots.items() if ref.robot is None}
        out: dict[int, Any] = {}
        for name, raw in req.data.items():
            number = numbers.get((req.sender, name))
            if number is None:
                return {}
            ref = self.m.slot_table.slots[number]
            try:
                value = msgspec.msgpack.decode(raw, type=resolve_type(ref.type))
            except (msgspec.MsgspecError, LookupError) as exc:
                return f"task {req.name!r}: its {name} datum is not a valid {ref.type}: {exc}"
            out[number] = msgspec.to_builtins(value)
        return out
