"""The DSP process's slots on the bus: the contract between ``modules/dsp`` and every module that drives it.

The DSP process (``python -m modules.dsp``) is the only owner of the serial port. Other modules never open it:

| slot (``cromat/<robot>/dsp/<slot>``) | dir | kind / safety | struct |
| --- | --- | --- | --- |
| ``commands``  | in  | stream, safe   | :class:`DspCommands` — written by telemetry, pan_tilt, path_follower |
| ``telemetry`` | out | state, unsafe  | :class:`modules.dsp.protocol.Telemetry` (fields the mask selects) |
| ``errors``    | out | stream, safe   | :class:`DspErrorReport` — DSP faults and refused/unacknowledged commands |
| ``link``      | out | state, unsafe  | :class:`modules.dsp.link.LinkStats` |
| ``error``     | out | state, safe    | :class:`bbcs.contracts.errors.ErrorReport` — the DSP process's own codes |

``commands`` is a mailbox input: many modules write to the DSP's own key (``keys.slot_key(robot, "dsp",
"commands")``), every batch is sent in order, each command acknowledged before the next. A batch is atomic in
the sense that matters: if one command fails, the rest of that batch is not sent, and the failure is reported on
``errors`` with the sender's name, so the sender can forward it (the path follower's ERROR slot does).
Start-up commands (telemetry mask, helicopter type, PID groups) come only from the robot .conf: the DSP process
refuses them on ``commands``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Annotated, Any

import msgspec

from bbcs.contracts.dsp import commands_slot
from bbcs.slots import InputSlot, Kind, OutputSlot, Publisher, Safety
from modules.dsp import protocol as p

DspCommand = (
    p.SetSpeed | p.SetStateTransmission | p.ClearError | p.SetTracking | p.InvalidatePath | p.SetMode
    | p.SetHeading | p.AddWaypoint | p.SetRefs | p.SetPanTiltMode | p.SetPanTiltAngles | p.SetPanTiltTarget
    | p.Abort | p.Ping
)
"""Every command another module may ask the DSP process to send (start-up-only ones excluded)."""

STARTUP_ONLY: tuple[type[p.Command], ...] = (p.SetTelemetryMask, p.SetHelicopterType, p.SetPid)

FORWARDED_DSP_ERROR_BASE = 1000
"""A DSP error about one of a module's own batches is forwarded on that module's ERROR as 1000 + the code."""

MODULE = "dsp"
COMMANDS_SLOT = "commands"
TELEMETRY_SLOT = "telemetry"
ERRORS_SLOT = "errors"
LINK_SLOT = "link"


def representable(x: float) -> bool:
    """Finite and within binary32: what the DSP (no doubles) can be sent."""
    return math.isfinite(x) and abs(x) <= p.F32_MAX


class DspCommands(msgspec.Struct, frozen=True, kw_only=True):
    """A batch of DSP commands from one module, sent in order."""

    sender: str
    """Module instance name of the writer (errors about this batch name it)."""
    commands: Annotated[list[DspCommand], msgspec.Meta(min_length=1, max_length=100_000)]
    batch_id: int = 0
    """Chosen by the sender, echoed in error reports about this batch."""


class DspErrorReport(msgspec.Struct, frozen=True, kw_only=True):
    """A DSP fault, or a command the DSP refused or never acknowledged."""

    code: int
    """A ``modules.dsp.protocol.ErrorCode`` value (DSP-side), or a link code (see docs/dsp_protocol.md)."""
    name: str
    detail: str
    sender: str = ""
    """Module whose batch failed; empty for faults the DSP reported on its own."""
    batch_id: int = 0
    command: str = ""


def telemetry_input() -> Any:
    """Input ``dsp_telemetry`` (handler ``on_dsp_telemetry``): the DSP's telemetry, newest value only."""
    return InputSlot("dsp_telemetry", p.Telemetry, safety=Safety.UNSAFE,
                     peer=f"{MODULE}/{TELEMETRY_SLOT}")


def errors_input() -> Any:
    """Input ``dsp_errors`` (handler ``on_dsp_errors``): the DSP's error reports, every one, in order."""
    return InputSlot("dsp_errors", DspErrorReport, kind=Kind.STREAM, peer=f"{MODULE}/{ERRORS_SLOT}")


def commands_output(sender: str | None = None) -> Any:
    """Output ``dsp_commands``: writes into the DSP process's command input for ``sender``
    (``dsp/commands_<sender>``, the key only that identity may write under access control, see
    bbcs.contracts.dsp); without a sender, the shared ``dsp/commands`` mailbox no identity may write under it."""
    slot = COMMANDS_SLOT if sender is None else commands_slot(sender)
    return OutputSlot("dsp_commands", DspCommands, kind=Kind.STREAM, peer=f"{MODULE}/{slot}")


class DspCommander:
    """Numbers and sends one module's command batches through its ``commands`` output."""

    def __init__(self, publisher: Publisher[DspCommands], sender: str) -> None:
        self.sender = sender
        self.batches = 0
        self.commands = 0
        self._pub = publisher

    def send(self, commands: Sequence[DspCommand]) -> int | None:
        """Send one batch; returns its id (None when there was nothing to send)."""
        if not commands:
            return None
        self.batches += 1
        self._pub.publish(DspCommands(sender=self.sender, commands=list(commands), batch_id=self.batches))
        self.commands += len(commands)
        return self.batches
