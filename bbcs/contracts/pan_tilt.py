"""Slot structs of the pan & tilt module, as seed 004 §5.3.2.2 defines them (field names are the seed's).

Its ERROR slot (the seed's ERROR_PT.error_pan_tilt) is :class:`bbcs.contracts.errors.ErrorReport`.

One definition each: every producer (ground station, vision, a tracker) imports DatosPT from here.
Ranges live in the types, so decoding is validation.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from bbcs.contracts.geo import DegreesSigned90, DegreesSigned180, Latitude, Longitude
from bbcs.contracts.slots import SlotNumber


class ControlEntradaPT(msgspec.Struct, frozen=True, kw_only=True):
    """CONTROL_ENTRADA_PT: which slot each routed input reads (-1 = ignore)."""

    slot_entrada_control_modos: SlotNumber = -1
    slot_entrada_datos: SlotNumber = -1


class DatosPT(msgspec.Struct, frozen=True, kw_only=True):
    """DATOS_PT: angle references (degrees) for mode 0, target point (WGS84 degrees, metres) for mode 1."""

    ref_pan: DegreesSigned180 = 0.0
    ref_tilt: DegreesSigned90 = 0.0
    latitud: Latitude = 0.0
    longitud: Longitude = 0.0
    altura: float = 0.0


class ModoFuncionamientoPT(msgspec.Struct, frozen=True, kw_only=True):
    """MODO_FUNCIONAMIENTO_PT: 0 angle references from DATOS; 1 point at the GPS target in DATOS;
    2 hold the current orientation with respect to local axes."""

    modo_de_funcionamiento: Annotated[int, msgspec.Meta(ge=0, le=2)]
    datos: DatosPT | None = None
    """The task's DATOS, carried with its mode (the four-hop command path, docs/bus.md): applied right after the
    mode, in the same DSP batch; a bad one refuses the whole message. None: the mode alone (DATOS arrive on their
    routed input, as from vision)."""
