"""Slot structs of the path follower / bridge, as seed 004 §5.3.2.3 defines them (field names are the seed's).

One definition each; ranges in the types. MAX_SPEED, known only from the robot .conf, is checked by the module
right after decoding. Its ERROR slot (the seed's ERROR_SEG_CAM.error_seg_cam) is
:class:`bbcs.contracts.errors.ErrorReport`.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from bbcs.contracts.geo import CommandSpeed, Latitude, Longitude, Radians
from bbcs.contracts.slots import SlotNumber


class ControlEntradaSegCam(msgspec.Struct, frozen=True, kw_only=True):
    """CONTROL_ENTRADA_SEG_CAM: which slot each routed input reads (-1 = ignore)."""

    slot_entrada_control_modos: SlotNumber = -1
    slot_entrada_heading: SlotNumber = -1
    slot_entrada_speed: SlotNumber = -1
    slot_entrada_datos: SlotNumber = -1


class HeadingSegCam(msgspec.Struct, frozen=True, kw_only=True):
    """HEADING_SEG_CAM: heading in radians, [-π, π); sent to the DSP in degrees, only in mode 1."""

    heading: Radians


class SpeedSegCam(msgspec.Struct, frozen=True, kw_only=True):
    """SPEED_SEG_CAM: navigation speed, m/s, [0, MAX_SPEED] (MAX_SPEED from the robot .conf)."""

    speed: CommandSpeed


SPEED_ACK_SLOT = "speed_ack"
"""The path follower's answer to each VELOCIDAD, after its SET_SPEED went out (docs/gcs.md, "speed before path")."""


class SpeedAck(msgspec.Struct, frozen=True, kw_only=True):
    """The path follower handled a VELOCIDAD: ``accepted`` means its SET_SPEED is on the DSP command stream, so
    every DATOS published after this answer is flown at ``speed``; refused with the module's ``code``."""

    speed: float
    accepted: bool
    code: int | None = None
    reason: str = ""


class DatoPuntoSegCam(msgspec.Struct, frozen=True, kw_only=True):
    """DATO_PUNTO_SEG_CAM: one waypoint (WGS84 degrees, metres). Heading is not part of a waypoint."""

    latitud: Latitude
    longitud: Longitude
    altura: float


class DatosSegCam(msgspec.Struct, frozen=True, kw_only=True):
    """DATOS stream: ``n_points`` then n waypoints; the whole trajectory arrives at once.

    A count that does not match the list (checked by the module right after decoding), n = 0, or any bad point
    rejects the whole message.
    """

    n_points: Annotated[int, msgspec.Meta(ge=1, le=2**32 - 1)]
    puntos: list[DatoPuntoSegCam]


class ControlModoSegCam(msgspec.Struct, frozen=True, kw_only=True):
    """CONTROL_MODO_SEG_CAM. ``modo_o_comando``: 0 change the operating mode, 1 a command.
    ``modo_de_funcionamiento``: 0 path following, DSP computes heading; 1 path following, heading from the
    HEADING slot; 2 semi-automatic; 3 onboard path follower; 4 take-off; 5 landing; 6 bridge.
    ``numero_de_comando``: 0 abort (empty the waypoint queues of the DSP and the onboard computer)."""

    modo_o_comando: Annotated[int, msgspec.Meta(ge=0, le=1)]
    modo_de_funcionamiento: Annotated[int, msgspec.Meta(ge=0, le=6)] = 0
    numero_de_comando: Annotated[int, msgspec.Meta(ge=0, le=0)] = 0
    velocidad: SpeedSegCam | None = None
    heading: HeadingSegCam | None = None
    datos: DatosSegCam | None = None
    """The task's data, carried with its mode (the four-hop command path, docs/bus.md): each field is what the
    same-named input would carry, applied right after the mode in this order (speed, heading, path), so the path is
    flown at its speed. Any bad one refuses the whole message and nothing is sent. None: that datum comes on its
    routed input, if at all (a source such as vision). A module restarted later gets the mode without its path
    (the Module Manager drops a delivered stream datum from the slot's kept value)."""


class RefsSegCam(msgspec.Struct, frozen=True, kw_only=True):
    """REFS_SEG_CAM: bridge references, sent as they are in mode 6. ``ref_rpm_motor`` in [0, 1800]
    (the seed's "1.800" is a Spanish thousands separator)."""

    ref_altura: float
    error_longitudinal: float
    error_lateral: float
    ref_heading: Radians
    ref_rpm_motor: Annotated[float, msgspec.Meta(ge=0.0, le=1800.0)]
