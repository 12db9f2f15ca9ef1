"""The telemetry process: subscribes the DSP process's telemetry, publishes RobotTelemetry for everyone.

Output slot ``telemetry`` (unsafe state: only the newest value matters) is read by the Module Manager, the RAL
and any module. Its one input is fixed, not routed: the DSP process's telemetry (``cromat/<robot>/dsp/telemetry``).
"""

from __future__ import annotations

from typing import ClassVar

from bbcs import Module, OutputSlot, Safety, dsp_client
from bbcs.contracts import dsp as p
from bbcs.contracts.robot import RobotTelemetry
from modules.telemetry.convert import to_robot_telemetry


class TelemetryModule(Module):
    name: ClassVar[str] = "telemetry"
    slots = (OutputSlot("telemetry", RobotTelemetry, safety=Safety.UNSAFE, priority="interactive_low"),  # ahead of bulk
             dsp_client.telemetry_input())

    def on_start(self) -> None:
        assert self.session is not None
        self.published = 0
        self.fields_dropped = 0

    def on_dsp_telemetry(self, t: p.Telemetry) -> None:
        value, dropped = to_robot_telemetry(t, self.bbcs_clock.time())  # stamped on the robot's clock
        if dropped:
            self.fields_dropped += len(dropped)
            self.log.warning(
                "DSP telemetry: invalid %s dropped (%d so far)", ", ".join(dropped), self.fields_dropped
            )
        self.publish("telemetry", value)
        self.published += 1
