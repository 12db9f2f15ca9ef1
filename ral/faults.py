"""When a DSP telemetry fault fails a task: only when it persists (pure, the RAL's clock passed in).

The DSP process refuses a telemetry frame that passed the CRC but is malformed or out of the ranges its types
declare, and reports it on its ERROR slot as TELEMETRY_REFUSED (105, at most once a second for a run of them,
modules/dsp/refusals.py). One such frame is a line fault the CRC let through: the frames before and after it are
good and the task flying on them is fine, so it must not fail the task as any other module error does
(ral/module.py ``_check_errors``). A fault that persists is another matter: if no valid telemetry follows a
refused frame for :data:`TELEMETRY_FAULT_WINDOW_S`, the robot is flying blind and every running task of the types
the DSP serves (movement, pan & tilt on a UAV) is failed with the reason.

The DSP's own faults are not judged here: a DSP ERROR message (GPS_LOST, LOW_BATTERY, ROTOR_RPM, SENSOR_FAULT) is
forwarded by the path follower as 1000 + code and fails the running tasks at once, as before, except a task that is
itself the answer to the fault (:func:`answers_fault`: a landing on a low battery).

Stamps are compared with stamps (the manager stamps the error when it receives it, the telemetry module stamps each
telemetry when it makes it: both the robot's clock), and the window is measured on the RAL's own clock from when the
RAL first saw the refusal, so the rule holds whatever clock the RAL's ``now`` is.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

from bbcs.contracts import mri
from bbcs.contracts.dsp import FORWARDED_DSP_ERROR_BASE, ErrorCode, LinkErrorCode
from bbcs.contracts.dsp import MODULE as DSP_MODULE
from bbcs.contracts.tasks import TaskInfo

TELEMETRY_FAULT_WINDOW_S = 3.0
"""A refused telemetry frame fails the running tasks only if no valid telemetry newer than it has reached the RAL
this long after the RAL learnt of it (the RAL sees telemetry with the manager's state, about once a second, so a
single bad frame is cleared by the next state; a GPS giving latitude 200° in every frame fails the task in 3-5 s)."""


ANSWERED_BY: dict[int, frozenset[str]] = {
    FORWARDED_DSP_ERROR_BASE + ErrorCode.LOW_BATTERY: frozenset({"land"}),
}
"""Forwarded DSP faults → the GRI kinds that answer them. Failing a landing because the battery is low would end
the one task the aircraft must finish (a campaign sequence found it: 200 sequences on one launch drained the
simulated battery, and the landing then flying was failed while it descended)."""


def answers_fault(task: TaskInfo, code: int) -> bool:
    """Whether ``task`` is itself what the robot does about the fault ``code``: then that fault does not fail it."""
    return (task.kind or task.name) in ANSWERED_BY.get(code, frozenset())


def is_telemetry_refusal(error: mri.ErrorEvent) -> bool:
    """A telemetry frame the DSP process refused (judged by :func:`judge`, not failed on at once)."""
    return error.module == DSP_MODULE and error.code == LinkErrorCode.TELEMETRY_REFUSED


@dataclass(frozen=True)
class TelemetryFault:
    """What the rule remembers between two manager states."""

    seen: float = 0.0
    """Stamp of the newest refusal already taken in."""
    last_valid: float | None = None
    """Stamp of the newest valid telemetry seen."""
    pending: float | None = None
    """Stamp of the first refusal that no valid telemetry has followed yet (None: no fault pending)."""
    noticed: float = 0.0
    """The RAL's clock when it first saw ``pending``."""


@dataclass(frozen=True)
class Verdict:
    state: TelemetryFault
    fail: str | None = None
    """The reason to fail the running tasks the DSP serves, when the fault persisted."""


def step(state: TelemetryFault, errors: Iterable[mri.ErrorEvent], telemetry_stamp: float | None, now: float,
         window_s: float = TELEMETRY_FAULT_WINDOW_S) -> Verdict:
    """Take in the manager's error list and its newest telemetry stamp; fail once a refusal has stood ``window_s``."""
    refusals = sorted(e.stamp for e in errors if is_telemetry_refusal(e) and e.stamp > state.seen)
    last_valid = state.last_valid
    if telemetry_stamp is not None and (last_valid is None or telemetry_stamp > last_valid):
        last_valid = telemetry_stamp
    pending, noticed = state.pending, state.noticed
    if pending is not None and last_valid is not None and last_valid > pending:
        pending = None  # good telemetry came after it: it was one bad frame (or a few)
    for stamp in refusals:
        if pending is None and (last_valid is None or stamp >= last_valid):
            pending, noticed = stamp, now
    new = replace(state, seen=refusals[-1] if refusals else state.seen, last_valid=last_valid, pending=pending,
                  noticed=noticed)
    if pending is not None and now - noticed >= window_s:
        reason = (f"DSP telemetry refused (TELEMETRY_REFUSED, {int(LinkErrorCode.TELEMETRY_REFUSED)}) and no valid "
                  f"telemetry after it for {window_s:g} s")
        return Verdict(replace(new, pending=None), fail=reason)
    return Verdict(new)


def judge(state: TelemetryFault, robot: mri.RobotState, running: Iterable[TaskInfo], now: float,
          window_s: float = TELEMETRY_FAULT_WINDOW_S) -> tuple[TelemetryFault, list[mri.EndTask]]:
    """:func:`step` on one manager state; the EndTask requests for the running tasks of the types the DSP serves
    when the fault persisted (none otherwise)."""
    stamp = robot.telemetry.stamp if robot.telemetry is not None else None
    verdict = step(state, robot.errors, stamp, now, window_s)
    if verdict.fail is None:
        return verdict.state, []
    serves = next((set(m.task_types) for m in robot.modules if m.name == DSP_MODULE), set())
    ends = [mri.EndTask(task_type=info.task_type, task_id=info.id, status="failed", detail=verdict.fail)
            for info in running if info.task_type in serves]
    return verdict.state, ends
