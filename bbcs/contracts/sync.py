"""Fleet time synchronisation on the bus (issue 17, docs/sync.md): clock probes, offset reports, synchronised
actions.

| key | what |
| --- | --- |
| ``cromat/<robot>/@ral/clock``        | queryable: a :class:`ClockProbe` in, a :class:`ClockEcho` out (NTP-style) |
| ``cromat/<robot>/@ral/clock_offsets`` | :class:`ClockReport`, the robot's measured offset to every peer |
| ``cromat/<robot>/@ral/sync``          | queryable: a :data:`SyncRequest` in, a :class:`SyncReply` out |

Times are seconds on the answering robot's own clock (its "sync clock": the host clock plus any injected skew).
``offset_s`` of a peer is ``peer_clock - own_clock``.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from bbcs import keys
from bbcs.contracts.geo import CommandSpeed
from bbcs.contracts.tasks import TaskParams

CLOCK = "clock"
CLOCK_OFFSETS = "clock_offsets"
SYNC = "sync"

Separation = Annotated[float, msgspec.Meta(ge=-1000.0, le=1000.0)]
"""Metres of a formation offset along one axis."""


class ClockProbe(msgspec.Struct, frozen=True, kw_only=True):
    t1: float
    """The asking side's clock when it sent the probe."""


class ClockEcho(msgspec.Struct, frozen=True, kw_only=True):
    robot: str
    t1: float
    """Echoed from the probe."""
    t2: float
    """The answering robot's clock when the probe arrived."""
    t3: float
    """The answering robot's clock when the echo left."""


class PeerOffset(msgspec.Struct, frozen=True, kw_only=True):
    peer: str
    offset_s: float
    """peer clock − own clock, from the minimum-delay sample of the window."""
    delay_s: float
    """Round-trip delay of that sample (the estimate's error is at most half of it)."""
    samples: int
    age_s: float
    """Seconds since that sample was taken."""


class ClockReport(msgspec.Struct, frozen=True, kw_only=True):
    robot: str
    stamp: float
    peers: list[PeerOffset] = msgspec.field(default_factory=list)


class SyncStart(msgspec.Struct, frozen=True, kw_only=True, tag="sync_start"):
    """Start ``task`` when ``reference``'s clock reads ``start_at`` (every robot of the group gets the same
    request: they start at one instant of the common time base)."""

    group: str
    reference: str
    """The robot whose clock is the time base of ``start_at``."""
    start_at: float
    task: TaskParams


class FormationKeep(msgspec.Struct, frozen=True, kw_only=True, tag="formation_keep"):
    """Keep ``north_m``/``east_m``/``up_m`` from ``leader``'s position (goto re-sent as the leader moves)."""

    leader: str
    north_m: Separation = 0.0
    east_m: Separation = 0.0
    up_m: Separation = 0.0
    speed: CommandSpeed | None = None


class StopFormation(msgspec.Struct, frozen=True, kw_only=True, tag="stop_formation"):
    """Stop following the leader (the running movement task is left as it is)."""


class SyncStatus(msgspec.Struct, frozen=True, kw_only=True, tag="sync_status"):
    """What this robot's synchronised starts of ``group`` did (``SyncReply.starts``)."""

    group: str


class SyncCancel(msgspec.Struct, frozen=True, kw_only=True, tag="sync_cancel"):
    """Do not start ``group`` after all (another robot of the group refused it): nothing half-happens."""

    group: str


SyncRequest = SyncStart | FormationKeep | StopFormation | SyncStatus | SyncCancel


class SyncStarted(msgspec.Struct, frozen=True, kw_only=True):
    group: str
    planned: float
    """The agreed instant on this robot's own clock."""
    started: float
    """This robot's own clock when its RAL started the task (the task then goes RAL → manager → modules)."""
    accepted: bool
    reason: str = ""
    task_id: int = 0


class SyncReply(msgspec.Struct, frozen=True, kw_only=True):
    accepted: bool
    reason: str = ""
    local_start: float | None = None
    """For a sync start: the instant on this robot's own clock at which it will start the task."""
    starts: list[SyncStarted] = msgspec.field(default_factory=list)
    """For a sync status: the starts of that group so far."""


def clock_key(robot: str) -> str:
    return keys.ral_key(robot, CLOCK)


def clock_offsets_key(robot: str) -> str:
    return keys.ral_key(robot, CLOCK_OFFSETS)


def sync_key(robot: str) -> str:
    return keys.ral_key(robot, SYNC)
