"""GRI events and errors as STATUSTEXT: which ones, with what severity, in 50-character chunks.

Every refusal and error a ground station of the GRI would see is told to the MAVLink side too: a rejected or failed
task, an abort, the link and failsafe events, a lost manager, a restarted module, each new entry of the robot's
error list. Accepted/completed tasks are told as INFO so a QGroundControl operator sees the flight's course.
"""

from __future__ import annotations

from dataclasses import dataclass

from bbcs.contracts import gri
from cromat.mavlink.dialect import mav

TEXT_LEN = 50
"""STATUSTEXT's text field; longer texts go in chunks (MAVLink 2 ``id`` + ``chunk_seq``)."""

SEVERITY: dict[str, int] = {
    "task_accepted": mav.MAV_SEVERITY_INFO,
    "task_completed": mav.MAV_SEVERITY_INFO,
    "task_cancelled": mav.MAV_SEVERITY_NOTICE,
    "task_replaced": mav.MAV_SEVERITY_INFO,
    "task_rejected": mav.MAV_SEVERITY_WARNING,
    "task_failed": mav.MAV_SEVERITY_ERROR,
    "aborted": mav.MAV_SEVERITY_WARNING,
    "link_up": mav.MAV_SEVERITY_INFO,
    "link_lost": mav.MAV_SEVERITY_WARNING,
    "failsafe": mav.MAV_SEVERITY_CRITICAL,
    "link_regained": mav.MAV_SEVERITY_NOTICE,
    "manager_lost": mav.MAV_SEVERITY_CRITICAL,
    "manager_back": mav.MAV_SEVERITY_NOTICE,
    "module_restarted": mav.MAV_SEVERITY_WARNING,
}


@dataclass(frozen=True, slots=True)
class Text:
    severity: int
    text: str


def event_text(event: gri.GriEvent) -> Text:
    """One GRI event as the operator reads it: ``uav1: task_failed movement #12: no progress for 30 s``."""
    task = f" {event.task_type}" if event.task_type else ""
    task += f" #{event.task_id}" if event.task_id else ""
    detail = f": {event.detail}" if event.detail else ""
    return Text(SEVERITY.get(event.kind, mav.MAV_SEVERITY_NOTICE), f"{event.robot}: {event.kind}{task}{detail}")


def error_text(robot: str, error: gri.ErrorRecord) -> Text:
    name = f" {error.name}" if error.name else ""
    detail = f": {error.detail}" if error.detail else ""
    return Text(mav.MAV_SEVERITY_ERROR, f"{robot}: {error.module} error {error.code}{name}{detail}")


def new_errors(seen: set[tuple[str, int, float]], errors: list[gri.ErrorRecord]) -> list[gri.ErrorRecord]:
    """The entries of a state's error list not told yet (``seen`` is updated; it keeps the last 256)."""
    fresh = [e for e in errors if (e.module, e.code, e.stamp) not in seen]
    seen.update((e.module, e.code, e.stamp) for e in fresh)
    if len(seen) > 256:
        for key in sorted(seen, key=lambda k: k[2])[: len(seen) - 256]:
            seen.discard(key)
    return fresh


def chunks(text: str, chunk_id: int) -> list[tuple[bytes, int, int]]:
    """``(text, id, chunk_seq)`` for each STATUSTEXT of ``text``: one with id 0 when it fits, else numbered chunks
    of one id (MAVSDK and QGroundControl join them); non-ASCII becomes ``?`` (the field is a char array)."""
    raw = text.encode("ascii", "replace")
    if len(raw) <= TEXT_LEN:
        return [(raw, 0, 0)]
    parts = [raw[i:i + TEXT_LEN] for i in range(0, len(raw), TEXT_LEN)]
    if len(parts[-1]) == TEXT_LEN:  # a full last chunk has no terminator: an empty one ends the text
        parts.append(b"")
    return [(part, chunk_id, seq) for seq, part in enumerate(parts)]
