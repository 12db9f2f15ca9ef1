"""The path follower / bridge process (SPEC §3.3): CONTROL_ENTRADA, CONTROL_MODO, HEADING, VELOCIDAD, DATOS,
REFS in; ERROR out; DSP commands out.

The decisions are in :mod:`modules.path_follower.logic`; this class wires them to the bus. CONTROL_MODO,
HEADING, VELOCIDAD and DATOS are routed by CONTROL_ENTRADA_SEG_CAM (-1: ignored); REFS is read on this
module's
own ``refs`` key. MAX_SPEED comes from the robot .conf (``--conf``): without it the module does not start.
DSP errors about this module's batches, and DSP faults that stop ordered tasks, are forwarded on ERROR.
"""

from __future__ import annotations

import math
from typing import ClassVar

import msgspec

from bbcs import ConfError, Control, InputSlot, Kind, Module, OutputSlot, Safety, dsp_client, load_conf
from bbcs.contracts import dsp as p
from bbcs.contracts.errors import ErrorReport
from bbcs.contracts.mri import MODE_ACK_SLOT, ModeAck, mode_echo
from bbcs.contracts.path_follower import (
    SPEED_ACK_SLOT,
    ControlEntradaSegCam,
    ControlModoSegCam,
    DatosSegCam,
    HeadingSegCam,
    RefsSegCam,
    SpeedAck,
    SpeedSegCam,
)
from modules.path_follower import logic

MODE_BATCH_MEMORY = 256
"""How many recent mode-change batches are remembered to undo the mode if the DSP refuses one."""


def load_max_speed(conf_path: str | None) -> float:
    """MAX_SPEED (m/s) of the robot .conf; ConfError (file, line) when missing or not a positive number."""
    if not conf_path:
        raise ConfError("the path follower needs the robot .conf (--conf) for MAX_SPEED", path="<none>")
    doc = load_conf(conf_path)
    text = doc.require("MAX_SPEED")
    entry = doc.entries["MAX_SPEED"]
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and 0.0 < value <= p.MAX_SPEED_LIMIT):
        raise ConfError(
            f"key 'MAX_SPEED': {text!r} is not a speed in (0, {p.MAX_SPEED_LIMIT}] m/s",
            path=doc.path,
            line=entry.line,
            column=entry.column,
        )
    return value


class PathFollowerModule(Module):
    name: ClassVar[str] = "path_follower"
    slots = (
        InputSlot("control_modo", ControlModoSegCam),
        InputSlot("heading", HeadingSegCam, safety=Safety.UNSAFE),
        InputSlot("velocidad", SpeedSegCam, safety=Safety.UNSAFE),
        InputSlot("datos", DatosSegCam, kind=Kind.STREAM),
        InputSlot("refs", RefsSegCam, safety=Safety.UNSAFE),
        dsp_client.telemetry_input(),
        dsp_client.errors_input(),
        dsp_client.commands_output("path_follower"),
        OutputSlot(MODE_ACK_SLOT, ModeAck),
        OutputSlot(SPEED_ACK_SLOT, SpeedAck),
        OutputSlot("error", ErrorReport),
    )
    control = Control(
        ControlEntradaSegCam,
        {
            "slot_entrada_control_modos": "control_modo",
            "slot_entrada_heading": "heading",
            "slot_entrada_speed": "velocidad",
            "slot_entrada_datos": "datos",
        },
    )
    error_slot = "error"
    field_codes = logic.FIELD_CODES

    def __init__(self, context) -> None:  # type: ignore[no-untyped-def]
        super().__init__(context)
        self.max_speed = load_max_speed(context.conf)

    def on_start(self) -> None:
        assert self.session is not None
        self.state = logic.FollowerState()
        self._mode_batches: dict[int, int | None] = {}
        self.dsp = dsp_client.DspCommander(self.output("dsp_commands"), self.module)
        # mode 3's follower (numpy, the LQR) is imported here, not with the class: the Module Manager imports
        # every module class to check the manifest, and numpy alone is ~0.1 s of its start-up
        from modules.path_follower import onboard

        self.onboard = onboard.OnboardFollower(onboard.OnboardParams(max_speed=self.max_speed))  # mode 3
        self._onboard_decide = onboard.decide

    def _ack_mode(self, msg: msgspec.Struct, decision: logic.Decision) -> None:
        """Answer the mode on MODE_ACK (after applying it): the manager's barrier before data for the new mode."""
        code = decision.errors[0] if decision.errors else None
        self.publish(MODE_ACK_SLOT, ModeAck(mode=mode_echo(msg), accepted=code is None, code=code,
                                            reason=decision.detail if code is not None else ""))

    def _apply(self, decision: logic.Decision) -> int | None:
        self.state = decision.state
        for code in decision.errors:
            self.report_error(code, decision.detail)
        batch = self.dsp.send(decision.commands)
        if batch is not None:
            self.log.debug("%s: batch %d, %d command(s)", decision.detail, batch, len(decision.commands))
        return batch

    def on_control_modo(self, msg: ControlModoSegCam) -> None:
        before = self.state.mode
        decision, data = logic.on_mode_message(self.state, msg, self.max_speed)
        batch = self._apply(decision)
        if not decision.errors:  # the task's data it carries, under the new mode (a batch of their own)
            if msg.velocidad is not None:
                self.onboard.set_speed(msg.velocidad.speed)
            if msg.heading is not None:
                self.onboard.set_heading(msg.heading.heading)
            self._apply(data)
        self._ack_mode(msg, decision)
        if batch is not None and msg.modo_o_comando == logic.MODE_CHANGE:
            self._mode_batches[batch] = before
            while len(self._mode_batches) > MODE_BATCH_MEMORY:
                del self._mode_batches[next(iter(self._mode_batches))]

    def on_heading(self, msg: HeadingSegCam) -> None:
        self.onboard.set_heading(msg.heading)
        self._apply(logic.on_heading(self.state, msg))

    def on_velocidad(self, msg: SpeedSegCam) -> None:
        if msg.speed <= self.max_speed:
            self.onboard.set_speed(msg.speed)
        decision = logic.on_velocidad(self.state, msg, self.max_speed)
        self._apply(decision)
        # after the SET_SPEED batch is on the command stream: a path its sender publishes after this answer goes
        # out behind it (one publisher, in order), so its first waypoint is flown at this speed
        code = decision.errors[0] if decision.errors else None
        self.publish(SPEED_ACK_SLOT, SpeedAck(speed=msg.speed, accepted=code is None, code=code,
                                             reason=decision.detail if code is not None else ""))

    def on_datos(self, msg: DatosSegCam) -> None:
        self._apply(logic.on_datos(self.state, msg))

    def on_refs(self, msg: RefsSegCam) -> None:
        self._apply(logic.on_refs(self.state, msg))

    def on_dsp_telemetry(self, t: p.Telemetry) -> None:
        self.state = logic.on_telemetry(self.state, t)
        self._apply(self._onboard_decide(self.onboard, self.state, t))

    def on_dsp_errors(self, report: p.DspErrorReport) -> None:
        own_mode_batch = report.sender == self.module and report.batch_id in self._mode_batches
        before = self._mode_batches.pop(report.batch_id, None) if own_mode_batch else None
        self._apply(
            logic.on_dsp_error(
                self.state, report, self.module, restore_mode=own_mode_batch, mode_before=before
            )
        )
