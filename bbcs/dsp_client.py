"""The slots a module declares to drive the DSP process over the bus (its contract: :mod:`bbcs.contracts.dsp`).

Telemetry, pan & tilt and the path follower never open the serial port: they read the DSP process's
``telemetry`` and ``errors`` outputs and write batches into their own ``commands_<sender>`` input of it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from bbcs.contracts.dsp import (
    ERRORS_SLOT,
    MODULE,
    TELEMETRY_SLOT,
    DspCommand,
    DspCommands,
    DspErrorReport,
    Telemetry,
    commands_slot,
)
from bbcs.slots import InputSlot, Kind, OutputSlot, Publisher, Safety


def telemetry_input() -> Any:
    """Input ``dsp_telemetry`` (handler ``on_dsp_telemetry``): the DSP's telemetry, newest value only."""
    return InputSlot("dsp_telemetry", Telemetry, safety=Safety.UNSAFE, peer=f"{MODULE}/{TELEMETRY_SLOT}")


def errors_input() -> Any:
    """Input ``dsp_errors`` (handler ``on_dsp_errors``): the DSP's error reports, every one, in order."""
    return InputSlot("dsp_errors", DspErrorReport, kind=Kind.STREAM, peer=f"{MODULE}/{ERRORS_SLOT}")


def commands_output(sender: str) -> Any:
    """Output ``dsp_commands``: writes into the DSP process's command input for ``sender``
    (``dsp/commands_<sender>``, the key only that identity may write under access control, see
    bbcs.contracts.dsp). There is no shared mailbox."""
    # abort travels here: ahead of bulk and perception data on every link, sent at once (issue 32)
    return OutputSlot("dsp_commands", DspCommands, kind=Kind.STREAM, peer=f"{MODULE}/{commands_slot(sender)}",
                      priority="interactive_high", express=True)


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
