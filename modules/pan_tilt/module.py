"""The pan & tilt process (SPEC §3.2): CONTROL_ENTRADA, CONTROL_MODO, DATOS in; ERROR out; DSP commands out.

The decisions are in :mod:`modules.pan_tilt.logic`; this class wires them to the bus. CONTROL_MODO and DATOS
are
routed inputs: CONTROL_ENTRADA_PT names the slot numbers they are read from (-1: ignored). The DSP's telemetry
gives the pan & tilt mode in force when the module (re)starts; the DSP's error reports about this module's own
batches are forwarded on ERROR.
"""

from __future__ import annotations

from typing import ClassVar

import msgspec

from bbcs import Control, InputSlot, Module, OutputSlot, Safety, dsp_client
from bbcs.contracts import dsp as p
from bbcs.contracts.errors import ErrorReport
from bbcs.contracts.mri import MODE_ACK_SLOT, ModeAck, mode_echo
from bbcs.contracts.pan_tilt import ControlEntradaPT, DatosPT, ModoFuncionamientoPT
from modules.pan_tilt import logic


class PanTiltModule(Module):
    name: ClassVar[str] = "pan_tilt"
    slots = (
        InputSlot("control_modo", ModoFuncionamientoPT),
        InputSlot("datos", DatosPT, safety=Safety.UNSAFE),
        OutputSlot("error", ErrorReport),
        dsp_client.telemetry_input(),
        dsp_client.errors_input(),
        dsp_client.commands_output("pan_tilt"),
        OutputSlot(MODE_ACK_SLOT, ModeAck),
    )
    control = Control(
        ControlEntradaPT, {"slot_entrada_control_modos": "control_modo", "slot_entrada_datos": "datos"}
    )
    error_slot = "error"
    field_codes = logic.FIELD_CODES

    def on_start(self) -> None:
        assert self.session is not None
        self.state = logic.PanTiltState()
        self.dsp = dsp_client.DspCommander(self.output("dsp_commands"), self.module)

    def _ack_mode(self, msg: msgspec.Struct, decision: logic.Decision) -> None:
        """Answer the mode on MODE_ACK (after applying it): the manager's barrier before data for the new mode."""
        code = decision.errors[0] if decision.errors else None
        self.publish(MODE_ACK_SLOT, ModeAck(mode=mode_echo(msg), accepted=code is None, code=code,
                                            reason=decision.detail if code is not None else ""))

    def _apply(self, decision: logic.Decision) -> None:
        self.state = decision.state
        for code in decision.errors:
            self.report_error(code, decision.detail)
        if decision.commands:
            self.dsp.send(decision.commands)
            self.log.debug("%s: %d command(s)", decision.detail, len(decision.commands))

    def on_control_modo(self, msg: ModoFuncionamientoPT) -> None:
        decision = logic.on_control_modo(self.state, msg)
        self._apply(decision)
        self._ack_mode(msg, decision)

    def on_datos(self, msg: DatosPT) -> None:
        self._apply(logic.on_datos(self.state, msg))

    def on_dsp_telemetry(self, t: p.Telemetry) -> None:
        self.state = logic.on_telemetry(self.state, t)

    def on_dsp_errors(self, report: p.DspErrorReport) -> None:
        self._apply(logic.on_dsp_error(self.state, report, self.module))
