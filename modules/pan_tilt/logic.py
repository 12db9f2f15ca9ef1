"""What the pan & tilt module decides, with no bus and no clock: datum in → DSP commands and error codes out.

SPEC §3.2 (seed 004 §5.3.2.2): a CONTROL_MODO datum goes to the DSP as it is; a DATOS datum sends the angle
references in mode 0, the target point in mode 1, nothing in mode 2. Ranges are checked by decoding (the
struct types); what decoding cannot see (a non-finite or binary32-overflowing altitude) is checked here. A
datum with any error produces no command at all (the seed's rule).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from bbcs.codec import leaf_field
from bbcs.contracts import dsp as p
from bbcs.contracts.dsp import FORWARDED_DSP_ERROR_BASE, DspCommand, DspErrorReport, representable
from bbcs.contracts.error_codes import PanTiltError
from bbcs.contracts.pan_tilt import DatosPT, ModoFuncionamientoPT

FIELD_CODES: dict[tuple[str, str], PanTiltError] = {
    ("control_entrada", "slot_entrada_control_modos"): PanTiltError.CONTROL_ENTRADA_OUT_OF_RANGE,
    ("control_entrada", "slot_entrada_datos"): PanTiltError.CONTROL_ENTRADA_OUT_OF_RANGE,
    ("control_modo", "modo_de_funcionamiento"): PanTiltError.MODE_OUT_OF_RANGE,
    # the DATOS a mode carries: the same codes as on their own input
    ("control_modo", "ref_pan"): PanTiltError.REF_PAN_OUT_OF_RANGE,
    ("control_modo", "ref_tilt"): PanTiltError.REF_TILT_OUT_OF_RANGE,
    ("control_modo", "latitud"): PanTiltError.LATITUD_OUT_OF_RANGE,
    ("control_modo", "longitud"): PanTiltError.LONGITUD_OUT_OF_RANGE,
    ("datos", "ref_pan"): PanTiltError.REF_PAN_OUT_OF_RANGE,
    ("datos", "ref_tilt"): PanTiltError.REF_TILT_OUT_OF_RANGE,
    ("datos", "latitud"): PanTiltError.LATITUD_OUT_OF_RANGE,
    ("datos", "longitud"): PanTiltError.LONGITUD_OUT_OF_RANGE,
    ("datos", "altura"): PanTiltError.ALTURA_NOT_REPRESENTABLE,
}


def field_code(slot: str, path: str) -> int | None:
    """The documented code for an out-of-range ``slot`` field (None: not one of ours)."""
    return FIELD_CODES.get((slot, leaf_field(path)))


@dataclass(frozen=True)
class PanTiltState:
    """The pan & tilt mode this module last gave the DSP; None until known (from a command or telemetry)."""

    mode: int | None = None
    mode_from_command: bool = False


@dataclass(frozen=True)
class Decision:
    """What one datum leads to: the new state, the commands to send (in order), the codes to report."""

    state: PanTiltState
    commands: tuple[DspCommand, ...] = ()
    errors: tuple[int, ...] = ()
    detail: str = ""


def on_control_modo(state: PanTiltState, msg: ModoFuncionamientoPT) -> Decision:
    """CONTROL_MODO: passed to the DSP as it is; the DATOS it carries (a task's, docs/bus.md) follow it in the same
    decision, handled under the new mode. A carried datum in error refuses the whole message: no command, the mode
    kept."""
    mode = p.PanTiltMode(msg.modo_de_funcionamiento)
    decision = Decision(
        PanTiltState(mode=int(mode), mode_from_command=True),
        (p.SetPanTiltMode(mode=mode),),
        detail=f"pan & tilt mode {mode.name}",
    )
    if msg.datos is None:
        return decision
    data = on_datos(decision.state, msg.datos)
    if data.errors:
        return Decision(state, errors=data.errors, detail=f"mode {mode.name} refused: {data.detail}")
    return Decision(data.state, decision.commands + data.commands, detail=f"{decision.detail}, {data.detail}")


def on_datos(state: PanTiltState, msg: DatosPT) -> Decision:
    """DATOS: mode 0 → angle references, mode 1 → target point, mode 2 (or not yet known) → nothing."""
    if state.mode == p.PanTiltMode.ANGLES:
        return Decision(
            state,
            (p.SetPanTiltAngles(pan_deg=msg.ref_pan, tilt_deg=msg.ref_tilt),),
            detail="angle references",
        )
    if state.mode == p.PanTiltMode.TARGET:
        if not representable(msg.altura):
            return Decision(
                state,
                errors=(PanTiltError.ALTURA_NOT_REPRESENTABLE,),
                detail=f"altura {msg.altura!r} cannot be sent to the DSP; datum dropped",
            )
        return Decision(
            state,
            (p.SetPanTiltTarget(lat=msg.latitud, lon=msg.longitud, alt=msg.altura),),
            detail="target point",
        )
    return Decision(state, detail=f"DATOS ignored in pan & tilt mode {state.mode}")


def on_telemetry(state: PanTiltState, telemetry: p.Telemetry) -> PanTiltState:
    """Adopt the DSP's pan & tilt mode until a CONTROL_MODO has set one (e.g. after a module restart)."""
    if state.mode_from_command or telemetry.pan_tilt is None:
        return state
    return replace(state, mode=telemetry.pan_tilt.mode)


def on_dsp_error(state: PanTiltState, report: DspErrorReport, module: str) -> Decision:
    """A refused or unacknowledged command of this module's own batch: forwarded on ERROR."""
    if report.sender != module:
        return Decision(state)
    return Decision(
        state,
        errors=(FORWARDED_DSP_ERROR_BASE + report.code,),
        detail=f"DSP refused {report.command or 'a command'}: {report.name} {report.detail}",
    )
