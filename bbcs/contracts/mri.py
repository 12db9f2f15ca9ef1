"""The MRI (Management Robot Interface): typed requests to one robot's Module Manager, and its robot state.

Every request is a Zenoh query on ``cromat/<robot>/@manager/<verb>`` whose payload is the request struct in
msgpack; every reply is an :class:`MriReply` (``ok``, or ``ok=False`` with a reason). The manager publishes
:class:`RobotState` on ``cromat/<robot>/@manager/state`` (safe state: a late joiner gets the last one).

| verb | request | reply ``data`` |
| --- | --- | --- |
| ``modules`` | :class:`ListModules` | :class:`ModuleList` |
| ``routes``  | :class:`ListRoutes`  | :class:`RouteList` |
| ``route``   | :class:`SwapRoute`   | :class:`RouteList` (routes after the swap) |
| ``module``  | :class:`ModuleCommand` (start/stop/restart) | :class:`ModuleStatus` |
| ``task``    | :class:`SetTask` / :class:`EndTask` | :class:`TaskList` |
| ``tasks``   | :class:`ListTasks`   | :class:`TaskList` |
| ``mode``    | :class:`SetModuleMode` | none |
| ``param``   | :class:`ListParams` / :class:`GetParam` / :class:`SetParam` (contracts/params.py) | :class:`ParamList` |
"""

from __future__ import annotations

import re
from typing import Any, Literal

import msgspec
import zenoh

from bbcs import bounded, keys
from bbcs.contracts.params import GetParam, ListParams, ParamChange, ParamList, SetParam
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.contracts.safety import Severity
from bbcs.contracts.tasks import Origin, TaskInfo, TaskParams

ModuleState = Literal["starting", "up", "restarting", "failed", "stopped"]
EndStatus = Literal["cancelled", "completed", "failed", "aborted"]
TaskType = str
"""A task type the manifest declares (UAV: ``perception``, ``movement``, ``pan_tilt``)."""

VERBS = ("modules", "routes", "route", "module", "task", "tasks", "mode", "param")
STATE = "state"
MANAGER_ACK_S = 5.0
"""How long the manager waits for the modules' RouteAcks of one change (one deadline for all of them)."""
REPLY_TIMEOUT_S = 2 * MANAGER_ACK_S
"""A caller's default wait for an MRI reply: longer than the manager's own ack wait, so a slow but successful
change is never reported to the caller as "no reply" while the manager goes on to apply it."""


class ListModules(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    pass


class ListRoutes(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    pass


class ListTasks(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    pass


class SwapRoute(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    """Route ``module``'s ``input`` slot to slot number ``slot`` (-1: ignore the input)."""

    module: str
    input: str
    slot: int


class ModuleCommand(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    module: str
    action: Literal["start", "stop", "restart"]


class SetTask(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    """Start task ``name`` (from the manifest's task map); it replaces the running task of the same type.

    ``params`` (typed, :mod:`bbcs.contracts.tasks`) travel with the task and are shown wherever it is listed."""

    name: str
    params: TaskParams | None = None
    origin: Origin = "mri"
    replaced_as: Literal["replaced", "aborted"] = "replaced"
    """How the task it replaces is recorded as having ended (an abort ends it as ``aborted``)."""
    data: dict[str, msgspec.Raw] = msgspec.field(default_factory=dict)
    """The task's data, by the name of ``sender``'s output slot each would be published on, each the msgpack of that
    slot's struct. Where every one of them reaches a module input the task's mode can carry (the mode struct has a
    field of the input's name), the manager sends them inside the mode: mode and data in one message, four hops
    from the ground station to the DSP (docs/bus.md, "The command path"). The reply's ``carried`` names them; the
    sender publishes the others on its slots."""
    sender: str = "ral"
    """The module whose output slots ``data`` names (the slot table maps its slots to numbers)."""


class EndTask(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    """End the running task of ``task_type`` (only if it is still task ``task_id``, when that is not 0); its routes
    and modes are restored to what they were before. ``status``/``detail`` say why it ended."""

    task_type: str
    task_id: int = 0
    status: EndStatus = "cancelled"
    detail: str = ""


class SetModuleMode(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    """Publish ``mode`` (msgpack of the module's mode struct, as a dict) on the manager's mode slot for ``module``."""

    module: str
    mode: dict[str, int]


MriRequest = (ListModules | ListRoutes | ListTasks | SwapRoute | ModuleCommand | SetTask | EndTask | SetModuleMode
              | ListParams | GetParam | SetParam)


class ModuleStatus(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    name: str
    state: ModuleState
    pid: int | None = None
    restarts: int = 0
    last_exit: int | None = None
    """Exit code of the last run (negative: killed by that signal)."""
    reason: str = ""
    """Why it is failed/stopped, when it is."""
    routes: dict[str, int] = msgspec.field(default_factory=dict)
    task_types: list[str] = msgspec.field(default_factory=list)
    last_error: int | None = None


class ModuleList(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    robot: str
    modules: list[ModuleStatus]


class RouteList(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    routes: dict[str, dict[str, int]]
    """module → input slot → slot number."""
    slots: dict[int, str] = msgspec.field(default_factory=dict)
    """slot number → ``module/slot`` (type in the manifest)."""


ActiveTask = TaskInfo
"""The task book's record of a task (one type, :class:`bbcs.contracts.tasks.TaskInfo`, for the MRI and the GRI)."""


class TaskList(msgspec.Struct, frozen=True, kw_only=True, tag=True):
    active: list[TaskInfo]
    ended: list[TaskInfo] = msgspec.field(default_factory=list)
    """The most recently ended tasks, newest last (bounded): how each one ended and why."""
    available: dict[str, str] = msgspec.field(default_factory=dict)
    """task name → task type: the manifest tasks a ground station can send (a GRI task kind of that name)."""
    version: int = 0
    """Grows with every change of the task book: an older list never overrides a newer one."""
    epoch: float = 0.0
    """When this task book began (the manager's start): a new epoch means every earlier task was lost."""


class ErrorEvent(msgspec.Struct, frozen=True, kw_only=True):
    module: str
    """Module name, or ``ral``."""
    code: int
    stamp: float
    name: str = ""
    """The code's name (``SPEED_ABOVE_MAX``) when the reporter knows it."""
    detail: str = ""
    severity: Severity | None = None
    """How grave (``bbcs.contracts.safety.Severity``: 1 warning, 2 error, 3 critical) when the reporter grades it
    (the RAL's loss-of-control errors do, ral/health.py); None: not graded."""


class RobotState(msgspec.Struct, frozen=True, kw_only=True):
    """The generic robot state: module health + robot telemetry, what the RAL serves to ground stations."""

    robot: str
    kind: str
    stamp: float
    telemetry: RobotTelemetry | None = None
    modules: list[ModuleStatus] = msgspec.field(default_factory=list)
    tasks: list[TaskInfo] = msgspec.field(default_factory=list)
    ended: list[TaskInfo] = msgspec.field(default_factory=list)
    task_version: int = 0
    task_epoch: float = 0.0
    errors: list[ErrorEvent] = msgspec.field(default_factory=list)
    """The most recent error codes from the modules' ERROR slots, newest last (bounded)."""
    home: GeoPoint | None = None
    """The take-off point: the last position the robot's telemetry gave on the ground. Kept by the manager, so a
    RAL restarted in flight still knows it (heights above home, ``return``)."""
    param_changes: list[ParamChange] = msgspec.field(default_factory=list)
    """The most recent accepted run-time parameter changes, oldest first (bounded; ``seq`` grows by one each):
    the RAL relays each new one as a ``param_changed`` GRI event."""


EFFECT_LOST = "the task's effect is lost"
"""How a task's failure detail ends when a module it relies on exited (``module dsp exited (-9): the task's effect
is lost``): the robot lost the means to carry it out, whatever the aircraft was doing (the safety monitor then
judges that the aircraft stops, not that it was still progressing)."""


def module_error_detail(module: str, code: int, name: str = "") -> str:
    """Why the RAL failed a task on a module's error (``module path_follower reported error 1007 DSP_LOW_BATTERY``):
    one wording, which :func:`reported_error` reads back (the safety monitor judges such failures by their code)."""
    return f"module {module} reported error {code}{' ' + name if name else ''}"


def reported_error(detail: str) -> int | None:
    """The code of a failure detail written by :func:`module_error_detail` (None: another reason)."""
    match = _REPORTED.match(detail)
    return int(match.group(1)) if match else None


_REPORTED = re.compile(r"module \S+ reported error (\d+)(?: |$)")


MODE_ACK_SLOT = "mode_ack"
"""Output slot on which a module that takes a mode answers every mode it receives."""


class ModeAck(msgspec.Struct, frozen=True, kw_only=True):
    """A module's answer to one mode (its fields as received, carried data included): applied, or refused with its
    error code and why.

    Published after the module has applied the mode, from the thread that handles its data: anything sent after
    this answer is handled under the new mode."""

    mode: dict[str, Any]
    accepted: bool
    code: int | None = None
    reason: str = ""


def mode_echo(mode: msgspec.Struct) -> dict[str, Any]:
    """A mode as its :class:`ModeAck` echoes it: its fields, the data it carries included, the absent (None) ones
    left out, so a mode without data echoes as it always did (``{"modo_de_funcionamiento": 1}``)."""
    return {k: v for k, v in msgspec.to_builtins(mode).items() if v is not None}


class MriReply(msgspec.Struct, frozen=True, kw_only=True):
    ok: bool
    reason: str = ""
    code: int | None = None
    """The refusing module's error code, when a module refused the request."""
    data: ModuleList | RouteList | ModuleStatus | TaskList | ParamList | None = None
    carried: list[str] = msgspec.field(default_factory=list)
    """SetTask: which of its ``data`` went to the modules inside the task's modes (all or none of them)."""


_request_decoder = msgspec.msgpack.Decoder(MriRequest)
_reply_decoder = msgspec.msgpack.Decoder(MriReply)


def mri_key(robot: str, verb: str) -> str:
    if verb not in VERBS and verb != STATE:
        raise ValueError(f"unknown MRI verb {verb!r}; known: {', '.join(VERBS)}")
    return keys.manager_key(robot, verb)


def decode_request(payload: bytes) -> MriRequest:
    """Decode = validate; too large or too deep is refused first (bbcs.bounded.RequestRefused)."""
    return bounded.decode(_request_decoder, payload)


def encode(value: msgspec.Struct) -> bytes:
    return msgspec.msgpack.encode(value)


class MriError(RuntimeError):
    """The manager did not answer (not running, unreachable) or its answer could not be read."""


def call(
    session: zenoh.Session, robot: str, verb: str, request: msgspec.Struct, timeout_s: float = REPLY_TIMEOUT_S
) -> MriReply:
    """Send one MRI request and wait for its typed reply; MriError if none arrives in ``timeout_s``."""
    replies = session.get(mri_key(robot, verb), payload=encode(request), timeout=timeout_s)
    for reply in replies:
        if reply.ok is None:
            continue
        try:
            return _reply_decoder.decode(reply.ok.payload.to_bytes())
        except msgspec.MsgspecError as exc:
            raise MriError(f"unreadable MRI reply from robot {robot!r} ({verb}): {exc}") from exc
    raise MriError(f"no MRI reply from robot {robot!r} for {verb!r} within {timeout_s:g} s: "
                   "is its Module Manager running and reachable?")
