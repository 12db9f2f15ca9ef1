"""Slot structs of the pan & tilt module, as seed 004 §5.3.2.2 defines them (field names are the seed's).

One definition each: every producer (ground station, vision, a tracker) imports DatosPT from here.
Ranges live in the types, so decoding is validation.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

SlotNumber = Annotated[int, msgspec.Meta(ge=-1)]
"""A slot-table number; -1 means "ignore this input"."""


class ControlEntradaPT(msgspec.Struct, frozen=True, kw_only=True):
    """CONTROL_ENTRADA_PT: which slot each routed input reads (-1 = ignore)."""

    slot_entrada_control_modos: SlotNumber = -1
    slot_entrada_datos: SlotNumber = -1


class ModoFuncionamientoPT(msgspec.Struct, frozen=True, kw_only=True):
    """MODO_FUNCIONAMIENTO_PT: 0 angle references from DATOS; 1 point at the GPS target in DATOS;
    2 hold the current orientation with respect to local axes."""

    modo_de_funcionamiento: Annotated[int, msgspec.Meta(ge=0, le=2)]


class DatosPT(msgspec.Struct, frozen=True, kw_only=True):
    """DATOS_PT: angle references (degrees) for mode 0, target point (WGS84 degrees, metres) for mode 1."""

    ref_pan: Annotated[float, msgspec.Meta(ge=-180.0, le=180.0)] = 0.0
    ref_tilt: Annotated[float, msgspec.Meta(ge=-90.0, le=90.0)] = 0.0
    latitud: Annotated[float, msgspec.Meta(ge=-90.0, le=90.0)] = 0.0
    longitud: Annotated[float, msgspec.Meta(ge=-180.0, le=180.0)] = 0.0
    altura: float = 0.0


class ErrorPT(msgspec.Struct, frozen=True, kw_only=True):
    """ERROR_PT: an error code of the pan & tilt module (see docs/error_codes.md)."""

    error_pan_tilt: int
