"""The telemetry process: subscribes the DSP process's telemetry, publishes RobotTelemetry for everyone.

Output slot ``telemetry`` (unsafe state: only the newest value matters) is read by the Module Manager, the RAL
and any module. It has no inputs of its own: the DSP telemetry key is fixed
(``cromat/<robot>/dsp/telemetry``).
"""

from __future__ import annotations

import time
from typing import ClassVar

from bbcs import keys
from bbcs.module import Module
from bbcs.robot import RobotTelemetry
from bbcs.slots import OutputSlot, Safety
from modules.dsp import bus as dsp_bus
from modules.dsp import protocol as p
from modules.telemetry.convert import to_robot_telemetry
from modules.telemetry.feed import Feed


class TelemetryModule(Module):
    name: ClassVar[str] = "telemetry"
    slots = (OutputSlot("telemetry", RobotTelemetry, safety=Safety.UNSAFE),)

    def on_start(self) -> None:
        assert self.session is not None
        self.published = 0
        self.fields_dropped = 0
        dsp = self.context.params.get("dsp", dsp_bus.MODULE)
        self.feed = Feed(
            self.session,
            keys.slot_key(self.robot, dsp, dsp_bus.TELEMETRY_SLOT),
            p.Telemetry,
            self._on_dsp_telemetry,
            self.lock,
            newest_only=True,
        )

    def _on_dsp_telemetry(self, t: p.Telemetry) -> None:
        value, dropped = to_robot_telemetry(t, time.time())
        if dropped:
            self.fields_dropped += len(dropped)
            self.log.warning(
                "DSP telemetry: invalid %s dropped (%d so far)", ", ".join(dropped), self.fields_dropped
            )
        self.publish("telemetry", value)
        self.published += 1

    def on_stop(self) -> None:
        feed = getattr(self, "feed", None)
        if feed is not None:
            feed.close()
