"""How a module drives the DSP process: numbered command batches on ``cromat/<robot>/dsp/commands``.

Shared by the pan & tilt and path follower modules. The DSP process sends each batch in order and reports a
failed batch on ``cromat/<robot>/dsp/errors`` with the sender's name and the batch id.
"""

from __future__ import annotations

from collections.abc import Sequence

import zenoh

from bbcs import keys
from bbcs.slots import Kind, OutputSlot, Publisher
from modules.dsp import bus as dsp_bus
from modules.dsp.bus import DspCommand, DspCommands


class DspCommander:
    """Publishes this module's batches to the DSP process's command mailbox (safe stream)."""

    def __init__(self, session: zenoh.Session, robot: str, sender: str, dsp: str = dsp_bus.MODULE) -> None:
        self.sender = sender
        self.batches = 0
        self.commands = 0
        self._pub = Publisher(
            session,
            keys.slot_key(robot, dsp, dsp_bus.COMMANDS_SLOT),
            OutputSlot(dsp_bus.COMMANDS_SLOT, DspCommands, kind=Kind.STREAM),
        )

    def send(self, commands: Sequence[DspCommand]) -> int | None:
        """Send one batch; returns its id (None when there was nothing to send)."""
        if not commands:
            return None
        self.batches += 1
        self._pub.publish(DspCommands(sender=self.sender, commands=list(commands), batch_id=self.batches))
        self.commands += len(commands)
        return self.batches

    def close(self) -> None:
        self._pub.close()
