"""The manager's side of ``cromat param``: the MRI ``param`` verb (list, get, set a module's parameters).

Values are typed and range-checked from the module class's declaration (``params_type``; ``bbcs.params``); only
the names in its ``runtime_params`` are set at run time, and only on a running module, which applies the value on
its event loop and answers before the manager replies. An accepted value is kept for the module's later starts
(until the manager stops: the manifest file is not rewritten) and recorded in the robot state's ``param_changes``,
which the RAL relays as ``param_changed`` GRI events. A refused change changes nothing, anywhere.
"""

from __future__ import annotations

import difflib
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import msgspec

from bbcs import params as bp
from bbcs.contracts import mri
from bbcs.contracts.params import (
    GetParam,
    ListParams,
    ParamApplied,
    ParamChange,
    ParamInfo,
    ParamList,
    SetParam,
    module_params_key,
)
from module_manager.manifest import ModuleInfo

MAX_CHANGES = 32
"""Accepted changes kept in the robot state (newest last)."""
APPLY_TIMEOUT_S = 5.0
"""How long the manager waits for the module's answer to a change."""


class ParamDesk:
    """The values set at run time (over the manifest's) and the record of accepted changes."""

    def __init__(self, robot: str) -> None:
        self.robot = robot
        self.overrides: dict[str, dict[str, str]] = {}
        self.changes: deque[ParamChange] = deque(maxlen=MAX_CHANGES)
        self.seq = 0
        self.lock = threading.Lock()

    def values(self, info: ModuleInfo, expand: Callable[[str], str]) -> dict[str, str]:
        """The module's params in force: the manifest's (placeholders expanded), then the accepted changes."""
        with self.lock:
            return {**{k: expand(v) for k, v in info.spec.params.items()}, **self.overrides.get(info.name, {})}

    def overrides_of(self, module: str) -> dict[str, str]:
        with self.lock:
            return dict(self.overrides.get(module, {}))

    def recent(self) -> list[ParamChange]:
        with self.lock:
            return list(self.changes)

    def handle(self, req: ListParams | GetParam | SetParam, modules: dict[str, ModuleInfo],
               expand: Callable[[str], str], running: Callable[[str], str | None], session: Any,
               touch: Callable[[], None], out: Callable[[str], None]) -> mri.MriReply:
        """Answer one request. ``running(module)`` is None when the module is up, else its state."""
        info = modules.get(req.module)
        if info is None:
            return mri.MriReply(ok=False, reason=f"no module {req.module!r} in robot {self.robot!r} (modules: "
                                                 f"{', '.join(modules)})")
        listing = bp.describe_params(info.name, info.params_type, self.values(info, expand), info.runtime_params)
        declared = info.params_type is not None
        if isinstance(req, ListParams):
            return mri.MriReply(ok=True, data=ParamList(module=info.name, declared=declared, params=listing))
        found = next((p for p in listing if p.name == req.name), None)
        if isinstance(req, GetParam):
            if found is None:
                return mri.MriReply(ok=False, reason=_unknown(info.name, req.name, listing))
            return mri.MriReply(ok=True, data=ParamList(module=info.name, declared=declared, params=[found]))
        return self._set(req, info, found, listing, running, session, touch, out)

    def _set(self, req: SetParam, info: ModuleInfo, found: ParamInfo | None, listing: list[ParamInfo],
             running: Callable[[str], str | None], session: Any, touch: Callable[[], None],
             out: Callable[[str], None]) -> mri.MriReply:
        one = [found] if found is not None else []
        data = ParamList(module=info.name, declared=info.params_type is not None, params=one)
        if info.params_type is not None and found is None:
            return mri.MriReply(ok=False, reason=_unknown(info.name, req.name, listing) + "; nothing changed")
        why = bp.check_set(info.name, info.params_type, info.runtime_params, req.name, req.value)
        if why:
            return mri.MriReply(ok=False, reason=f"{why}; nothing changed", data=data)
        state = running(info.name)
        if state is not None:
            return mri.MriReply(ok=False, reason=f"module {info.name} is {state}: a run-time parameter is set on the "
                                                 "running module; nothing changed", data=data)
        answer = _ask(session, module_params_key(self.robot, info.name), req)
        if answer is None:
            return mri.MriReply(ok=False, reason=f"module {info.name} did not answer the change within "
                                                 f"{APPLY_TIMEOUT_S:g} s; nothing recorded", data=data)
        if not answer.ok:
            return mri.MriReply(ok=False, reason=f"module {info.name} refused it: {answer.reason}; nothing changed",
                                data=data)
        old = "" if found is None or found.value is None else _text(found.value)
        new = _text(answer.value)
        with self.lock:
            self.overrides.setdefault(info.name, {})[req.name] = req.value
            self.seq += 1
            self.changes.append(ParamChange(seq=self.seq, stamp=time.time(), module=info.name, name=req.name,
                                            old=old, new=new))
        touch()
        out(f"manager: {info.name}.{req.name} = {new} (was {old}), set at run time")
        assert found is not None
        return mri.MriReply(ok=True, data=ParamList(module=info.name, declared=True, params=[
            msgspec.structs.replace(found, value=answer.value)]))


def _text(value: Any) -> str:
    return str(value).lower() if isinstance(value, bool) else str(value)


def _unknown(module: str, name: str, listing: list[ParamInfo]) -> str:
    names = [p.name for p in listing]
    near = difflib.get_close_matches(name, names, n=1, cutoff=0.75)
    hint = f"did you mean {near[0]}? " if near else ""
    return f"{module} has no parameter {name!r} ({hint}parameters: {', '.join(names) or 'none'})"


_applied = msgspec.msgpack.Decoder(ParamApplied)


def _ask(session: Any, key: str, req: SetParam) -> ParamApplied | None:
    for reply in session.get(key, payload=msgspec.msgpack.encode(req), timeout=APPLY_TIMEOUT_S):
        if reply.ok is None:
            continue
        try:
            return _applied.decode(reply.ok.payload.to_bytes())
        except msgspec.MsgspecError:
            return None
    return None
