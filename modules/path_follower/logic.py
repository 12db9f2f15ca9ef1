"""What the path follower / bridge decides, with no bus and no clock: datum in → DSP commands and codes out.

SPEC §3.3 (seed 004 §5.3.2.3), one function per input slot. Each takes the current :class:`FollowerState`
and a datum that already decoded (so its struct ranges hold) and returns a :class:`Decision`: the new state,
the DSP commands to send in order, and the error codes to report. A datum with any error yields no command
and leaves the state as it was (the seed's rule: no datum affected by an error is computed, sent or used).

The "onboard queue" is the trajectory this module keeps (the whole DATOS message arrives at once so an onboard
follower can use it). A new DATOS replaces the path (both queues emptied, the DSP's acknowledged empty, before its
first waypoint goes out); the abort command empties both queues.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from bbcs.codec import leaf_field
from bbcs.contracts import dsp as p
from bbcs.contracts.dsp import FORWARDED_DSP_ERROR_BASE, DspCommand, DspErrorReport, representable
from bbcs.contracts.error_codes import FollowerError
from bbcs.contracts.path_follower import (
    ControlModoSegCam,
    DatoPuntoSegCam,
    DatosSegCam,
    HeadingSegCam,
    RefsSegCam,
    SpeedSegCam,
)

MODE_CHANGE = 0
COMMAND = 1
ABORT = 0

FIELD_CODES: dict[tuple[str, str], FollowerError] = {
    ("control_entrada", "slot_entrada_control_modos"): FollowerError.CONTROL_ENTRADA_OUT_OF_RANGE,
    ("control_entrada", "slot_entrada_heading"): FollowerError.CONTROL_ENTRADA_OUT_OF_RANGE,
    ("control_entrada", "slot_entrada_speed"): FollowerError.CONTROL_ENTRADA_OUT_OF_RANGE,
    ("control_entrada", "slot_entrada_datos"): FollowerError.CONTROL_ENTRADA_OUT_OF_RANGE,
    ("control_modo", "modo_o_comando"): FollowerError.MODO_O_COMANDO_OUT_OF_RANGE,
    ("control_modo", "modo_de_funcionamiento"): FollowerError.MODE_OUT_OF_RANGE,
    ("control_modo", "numero_de_comando"): FollowerError.COMMAND_OUT_OF_RANGE,
    # the data a mode carries: the same codes as on their own inputs
    ("control_modo", "heading"): FollowerError.HEADING_OUT_OF_RANGE,
    ("control_modo", "speed"): FollowerError.SPEED_OUT_OF_RANGE,
    ("control_modo", "n_points"): FollowerError.N_POINTS_OUT_OF_RANGE,
    ("control_modo", "latitud"): FollowerError.LATITUD_OUT_OF_RANGE,
    ("control_modo", "longitud"): FollowerError.LONGITUD_OUT_OF_RANGE,
    ("heading", "heading"): FollowerError.HEADING_OUT_OF_RANGE,
    ("velocidad", "speed"): FollowerError.SPEED_OUT_OF_RANGE,
    ("datos", "n_points"): FollowerError.N_POINTS_OUT_OF_RANGE,
    ("datos", "latitud"): FollowerError.LATITUD_OUT_OF_RANGE,
    ("datos", "longitud"): FollowerError.LONGITUD_OUT_OF_RANGE,
    ("refs", "ref_heading"): FollowerError.REF_HEADING_OUT_OF_RANGE,
    ("refs", "ref_rpm_motor"): FollowerError.REF_RPM_OUT_OF_RANGE,
}


def field_code(slot: str, path: str) -> int | None:
    """The documented code for an out-of-range ``slot`` field (None: not one of ours)."""
    return FIELD_CODES.get((slot, leaf_field(path)))


@dataclass(frozen=True)
class FollowerState:
    """The operating mode this module last set on the DSP (None until known) and the onboard trajectory."""

    mode: int | None = None
    mode_from_command: bool = False
    path: tuple[DatoPuntoSegCam, ...] = ()
    """The onboard waypoint queue: every point sent to the DSP since it was last emptied."""
    heading_deg: float | None = None
    """Current heading from the latest DSP telemetry (degrees)."""


@dataclass(frozen=True)
class Decision:
    """What one datum leads to: the new state, the commands to send (in order), the codes to report."""

    state: FollowerState
    commands: tuple[DspCommand, ...] = ()
    errors: tuple[int, ...] = ()
    detail: str = ""


def _refused(state: FollowerState, code: FollowerError, detail: str) -> Decision:
    return Decision(state, errors=(int(code),), detail=detail)


def on_control_modo(state: FollowerState, msg: ControlModoSegCam) -> Decision:
    """CONTROL_MODO: the abort command, or one row of SPEC §3.3's mode table."""
    if msg.modo_o_comando == COMMAND:
        if msg.numero_de_comando == ABORT:
            return Decision(
                replace(state, path=()), (p.Abort(),), detail="abort: both waypoint queues emptied"
            )
        return _refused(state, FollowerError.COMMAND_OUT_OF_RANGE, f"unknown command {msg.numero_de_comando}")
    mode = p.Mode(msg.modo_de_funcionamiento)
    new = replace(state, mode=int(mode), mode_from_command=True)
    if mode == p.Mode.PATH_AUTO_HEADING:
        cmds: tuple[DspCommand, ...] = (p.SetMode(mode=mode), p.SetTracking(enable=True))
    elif mode == p.Mode.PATH_GIVEN_HEADING:
        if state.heading_deg is None:
            return _refused(
                state,
                FollowerError.HEADING_UNKNOWN,
                "mode 1 needs the current heading and no DSP telemetry has given it yet",
            )
        heading = p.heading_deg_from_rad(math.radians(state.heading_deg))
        cmds = (p.SetHeading(heading_deg=heading), p.SetMode(mode=mode), p.SetTracking(enable=True))
    elif mode == p.Mode.SEMI_AUTOMATIC:
        cmds = (p.SetMode(mode=mode), p.SetTracking(enable=False), p.InvalidatePath())
        new = replace(new, path=())
    elif mode == p.Mode.ONBOARD_FOLLOWER:  # the trajectory is flown from here: modules/path_follower/onboard.py
        # the DSP's queue emptied: it is not flown in this mode, and a path of the task before left in it would be
        # flown again the moment a later mode 0/1 turned tracking on, before that task's own path replaced it
        cmds = (p.SetMode(mode=mode), p.InvalidatePath())
        new = replace(new, path=())
    elif mode in (p.Mode.TAKE_OFF, p.Mode.LANDING):
        cmds = (p.SetTracking(enable=False), p.InvalidatePath(), p.SetMode(mode=mode))
        new = replace(new, path=())
    else:  # BRIDGE
        cmds = (p.SetMode(mode=mode),)
    return Decision(new, cmds, detail=f"mode {mode.name}")


def on_mode_message(state: FollowerState, msg: ControlModoSegCam, max_speed: float) -> tuple[Decision, Decision]:
    """A CONTROL_MODO and the task data it carries (docs/bus.md, "The command path"): the mode's decision, then the
    data's, handled under the new mode in the order speed, heading, path (so the path is flown at its speed). Two
    decisions, so the mode goes out as its own batch (a DSP refusal of it restores the mode before). A carried datum
    in error refuses the whole message: the first decision holds its code and no command, the state is unchanged."""
    mode = on_control_modo(state, msg)
    empty = Decision(mode.state)
    if mode.errors or (msg.velocidad is None and msg.heading is None and msg.datos is None):
        return mode, empty
    new, commands, details = mode.state, (), []
    parts = ((msg.velocidad, lambda s, v: on_velocidad(s, v, max_speed)), (msg.heading, on_heading),
             (msg.datos, on_datos))
    for datum, handle in parts:
        if datum is None:
            continue
        data = handle(new, datum)
        if data.errors:
            return Decision(state, errors=data.errors, detail=f"{mode.detail} refused: {data.detail}"), Decision(state)
        new, commands, details = data.state, commands + data.commands, [*details, data.detail]
    return mode, Decision(new, commands, detail=", ".join(details))


def on_heading(state: FollowerState, msg: HeadingSegCam) -> Decision:
    """HEADING: radians → degrees → DSP in mode 1 only; ignored otherwise."""
    if state.mode != p.Mode.PATH_GIVEN_HEADING:
        return Decision(state, detail=f"HEADING ignored in mode {state.mode}")
    return Decision(state, (p.SetHeading(heading_deg=p.heading_deg_from_rad(msg.heading)),), detail="heading")


def on_velocidad(state: FollowerState, msg: SpeedSegCam, max_speed: float) -> Decision:
    """VELOCIDAD: always sent, once checked against MAX_SPEED."""
    if not msg.speed <= max_speed:
        return _refused(
            state,
            FollowerError.SPEED_ABOVE_MAX,
            f"speed {msg.speed!r} m/s above MAX_SPEED {max_speed} m/s; not sent",
        )
    return Decision(state, (p.SetSpeed(speed=msg.speed),), detail="speed")


def on_datos(state: FollowerState, msg: DatosSegCam, capacity: int = p.WAYPOINT_QUEUE_CAPACITY) -> Decision:
    """DATOS: in modes 0/1 a new path: both queues (onboard and DSP) emptied, then every waypoint; ignored otherwise.

    The whole message is checked first: a count that does not match, or any bad point, rejects all of it.
    """
    if msg.n_points != len(msg.puntos):
        return _refused(
            state,
            FollowerError.N_POINTS_MISMATCH,
            f"n_points={msg.n_points} but {len(msg.puntos)} points; whole path rejected",
        )
    for i, pt in enumerate(msg.puntos):
        if not representable(pt.altura):
            return _refused(
                state,
                FollowerError.ALTURA_NOT_REPRESENTABLE,
                f"point {i}: altura {pt.altura!r} cannot be sent to the DSP; whole path rejected",
            )
    if state.mode == p.Mode.ONBOARD_FOLLOWER:  # kept here for the onboard follower, not queued on the DSP
        return Decision(replace(state, path=state.path + tuple(msg.puntos)), detail=f"{msg.n_points} points onboard")
    if state.mode not in (p.Mode.PATH_AUTO_HEADING, p.Mode.PATH_GIVEN_HEADING):
        return Decision(state, detail=f"DATOS ignored in mode {state.mode}")
    if msg.n_points > capacity:
        return _refused(
            state,
            FollowerError.PATH_TOO_LONG,
            f"{msg.n_points} points exceed the DSP's waypoint queue ({capacity}); whole path rejected",
        )
    # replace means replace: the DSP's queue is emptied first, and the link sends each command only after the
    # previous one is acknowledged, so no new waypoint goes out before the DSP has confirmed its queue is empty
    cmds = (p.InvalidatePath(),) + tuple(
        p.AddWaypoint(lat=pt.latitud, lon=pt.longitud, alt=pt.altura) for pt in msg.puntos
    )
    return Decision(replace(state, path=tuple(msg.puntos)), cmds, detail=f"{msg.n_points} waypoints (replacing)")


def on_refs(state: FollowerState, msg: RefsSegCam) -> Decision:
    """REFS: sent as they are in mode 6 only; ignored otherwise."""
    for name in ("ref_altura", "error_longitudinal", "error_lateral"):
        if not representable(getattr(msg, name)):
            return _refused(
                state,
                FollowerError.REF_NOT_REPRESENTABLE,
                f"{name}={getattr(msg, name)!r} cannot be sent to the DSP; REFS dropped",
            )
    if state.mode != p.Mode.BRIDGE:
        return Decision(state, detail=f"REFS ignored in mode {state.mode}")
    return Decision(
        state,
        (
            p.SetRefs(
                ref_altura=msg.ref_altura,
                error_longitudinal=msg.error_longitudinal,
                error_lateral=msg.error_lateral,
                ref_heading=msg.ref_heading,
                ref_rpm_motor=msg.ref_rpm_motor,
            ),
        ),
        detail="bridge references",
    )


def on_telemetry(state: FollowerState, telemetry: p.Telemetry) -> FollowerState:
    """Keep the current heading; adopt the DSP's mode until a CONTROL_MODO has set one (module restart)."""
    heading = (
        telemetry.heading
        if telemetry.heading is not None
        else (telemetry.attitude.yaw if telemetry.attitude is not None else None)
    )
    new = state if heading is None or not math.isfinite(heading) else replace(state, heading_deg=heading)
    if not new.mode_from_command and telemetry.status is not None:
        new = replace(new, mode=telemetry.status.mode)
    return new


def on_dsp_error(
    state: FollowerState,
    report: DspErrorReport,
    module: str,
    *,
    restore_mode: bool = False,
    mode_before: int | None = None,
) -> Decision:
    """A DSP error that affects the tasks ordered from above → forwarded on ERROR as 1000 + code.

    Those are failures of this module's own batches and the DSP's flight faults (``dsp.FLIGHT_FAULTS``). When
    the failed batch was a mode change (``restore_mode``), ``mode_before`` is restored: the DSP did not change
    mode.
    """
    own = report.sender == module
    if not own and not (report.sender == "" and report.code in p.FLIGHT_FAULTS):
        return Decision(state)
    new = replace(state, mode=mode_before) if own and restore_mode else state
    return Decision(
        new,
        errors=(FORWARDED_DSP_ERROR_BASE + report.code,),
        detail=f"DSP error {report.name} ({report.code}) {report.command} {report.detail}".strip(),
    )
