"""The manager's accepted run-time parameter changes (``RobotState.param_changes``, ``cromat param set``) relayed
as ``param_changed`` GRI events, each once: ``detail`` = ``module.name = new (was old)``."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from bbcs.contracts import mri


@dataclass
class Seen:
    """What has been relayed: the manager's epoch and the last change's ``seq`` in it. Changes made before this
    RAL started are not relayed (a restarted RAL does not announce them again)."""

    start: float = field(default_factory=time.time)
    epoch: float | None = None
    seq: int = 0


def relay(ms: mri.RobotState, seen: Seen, emit: Callable[..., None]) -> None:
    if ms.task_epoch != seen.epoch:  # a new manager: its changes count from 1 again
        seen.epoch, seen.seq = ms.task_epoch, 0
    for change in ms.param_changes:
        if change.seq <= seen.seq:
            continue
        seen.seq = change.seq
        if change.stamp >= seen.start:
            emit("param_changed", detail=f"{change.module}.{change.name} = {change.new} (was {change.old})")
