"""Pan & tilt decisions (SPEC §3.2) and every range bound of its structs, without processes."""

from __future__ import annotations

import math

import msgspec
import pytest

from bbcs.codec import field_of
from bbcs.contracts import dsp as p
from bbcs.contracts.dsp import DspErrorReport
from bbcs.contracts.error_codes import PanTiltError
from bbcs.contracts.pan_tilt import ControlEntradaPT, DatosPT, ModoFuncionamientoPT
from modules.pan_tilt import logic
from modules.pan_tilt.logic import PanTiltState

DATOS = DatosPT(ref_pan=30.0, ref_tilt=-20.0, latitud=37.41, longitud=-6.0, altura=50.0)


@pytest.mark.parametrize("mode", [0, 1, 2])
def test_control_modo_passed_as_is(mode):
    d = logic.on_control_modo(PanTiltState(), ModoFuncionamientoPT(modo_de_funcionamiento=mode))
    assert d.commands == (p.SetPanTiltMode(mode=p.PanTiltMode(mode)),)
    assert d.errors == ()
    assert d.state.mode == mode and d.state.mode_from_command


def test_datos_mode_0_sends_angles():
    d = logic.on_datos(PanTiltState(mode=0), DATOS)
    assert d.commands == (p.SetPanTiltAngles(pan_deg=30.0, tilt_deg=-20.0),)


def test_datos_mode_1_sends_target():
    d = logic.on_datos(PanTiltState(mode=1), DATOS)
    assert d.commands == (p.SetPanTiltTarget(lat=37.41, lon=-6.0, alt=50.0),)


@pytest.mark.parametrize("mode", [2, None])
def test_datos_mode_2_or_unknown_sends_nothing(mode):
    d = logic.on_datos(PanTiltState(mode=mode), DATOS)
    assert d.commands == () and d.errors == ()


@pytest.mark.parametrize("alt", [math.nan, math.inf, -math.inf, 1e39])
def test_target_altitude_the_dsp_cannot_take_is_an_error(alt):
    d = logic.on_datos(PanTiltState(mode=1), msgspec.structs.replace(DATOS, altura=alt))
    assert d.commands == () and d.errors == (PanTiltError.ALTURA_NOT_REPRESENTABLE,)


def test_telemetry_mode_adopted_until_a_command_sets_it():
    t = p.Telemetry(time_ms=0, pan_tilt=p.PanTiltState(mode=0, pan=0.0, tilt=0.0))
    s = logic.on_telemetry(PanTiltState(), t)
    assert s.mode == 0
    s = logic.on_control_modo(s, ModoFuncionamientoPT(modo_de_funcionamiento=2)).state
    assert logic.on_telemetry(s, t).mode == 2


def test_dsp_errors_of_own_batches_forwarded():
    own = DspErrorReport(code=2, name="WRONG_MODE", detail="", sender="pan_tilt", batch_id=3)
    other = DspErrorReport(code=2, name="WRONG_MODE", detail="", sender="path_follower", batch_id=3)
    assert logic.on_dsp_error(PanTiltState(), own, "pan_tilt").errors == (1002,)
    assert logic.on_dsp_error(PanTiltState(), other, "pan_tilt").errors == ()


# every range bound: (slot, struct, field, in-range bound, just outside, code)
BOUNDS = [
    (
        "control_entrada",
        ControlEntradaPT,
        "slot_entrada_control_modos",
        -1,
        -2,
        PanTiltError.CONTROL_ENTRADA_OUT_OF_RANGE,
    ),
    (
        "control_entrada",
        ControlEntradaPT,
        "slot_entrada_datos",
        -1,
        -2,
        PanTiltError.CONTROL_ENTRADA_OUT_OF_RANGE,
    ),
    ("control_modo", ModoFuncionamientoPT, "modo_de_funcionamiento", 0, -1, PanTiltError.MODE_OUT_OF_RANGE),
    ("control_modo", ModoFuncionamientoPT, "modo_de_funcionamiento", 2, 3, PanTiltError.MODE_OUT_OF_RANGE),
    ("datos", DatosPT, "ref_pan", -180.0, -180.001, PanTiltError.REF_PAN_OUT_OF_RANGE),
    ("datos", DatosPT, "ref_pan", 180.0, 180.001, PanTiltError.REF_PAN_OUT_OF_RANGE),
    ("datos", DatosPT, "ref_tilt", -90.0, -90.001, PanTiltError.REF_TILT_OUT_OF_RANGE),
    ("datos", DatosPT, "ref_tilt", 90.0, 90.001, PanTiltError.REF_TILT_OUT_OF_RANGE),
    ("datos", DatosPT, "latitud", -90.0, -90.001, PanTiltError.LATITUD_OUT_OF_RANGE),
    ("datos", DatosPT, "latitud", 90.0, 90.001, PanTiltError.LATITUD_OUT_OF_RANGE),
    ("datos", DatosPT, "longitud", -180.0, -180.001, PanTiltError.LONGITUD_OUT_OF_RANGE),
    ("datos", DatosPT, "longitud", 180.0, 180.001, PanTiltError.LONGITUD_OUT_OF_RANGE),
]
BASE = {ModoFuncionamientoPT: {"modo_de_funcionamiento": 0}, ControlEntradaPT: {}, DatosPT: {}}


@pytest.mark.parametrize("slot,typ,field,inside,outside,code", BOUNDS)
def test_every_range_bound(slot, typ, field, inside, outside, code):
    dec = msgspec.msgpack.Decoder(typ)
    assert getattr(dec.decode(msgspec.msgpack.encode({**BASE[typ], field: inside})), field) == inside
    with pytest.raises(msgspec.ValidationError) as info:
        dec.decode(msgspec.msgpack.encode({**BASE[typ], field: outside}))
    assert logic.field_code(slot, field_of(info.value)) == code


def test_altura_is_unbounded_in_the_struct():
    dec = msgspec.msgpack.Decoder(DatosPT)
    assert dec.decode(msgspec.msgpack.encode({"altura": -1e300})).altura == -1e300


def test_a_mode_carrying_its_datos_sends_both_under_the_new_mode():
    """The four-hop path (docs/bus.md): mode and data in one message, the data handled under the new mode."""
    d = logic.on_control_modo(PanTiltState(mode=2), ModoFuncionamientoPT(modo_de_funcionamiento=1, datos=DATOS))
    assert d.commands == (p.SetPanTiltMode(mode=p.PanTiltMode.TARGET),
                          p.SetPanTiltTarget(lat=DATOS.latitud, lon=DATOS.longitud, alt=DATOS.altura))
    assert d.errors == () and d.state.mode == 1


def test_a_bad_carried_datos_refuses_the_mode_too():
    before = PanTiltState(mode=2, mode_from_command=True)
    bad = DatosPT(latitud=37.0, longitud=-6.0, altura=1e300)
    d = logic.on_control_modo(before, ModoFuncionamientoPT(modo_de_funcionamiento=1, datos=bad))
    assert d.commands == () and d.errors == (PanTiltError.ALTURA_NOT_REPRESENTABLE,) and d.state == before


def test_a_carried_datos_range_error_has_its_own_code():
    dec = msgspec.msgpack.Decoder(ModoFuncionamientoPT)
    raw = msgspec.msgpack.encode({"modo_de_funcionamiento": 0, "datos": {"ref_pan": 181.0}})
    with pytest.raises(msgspec.ValidationError) as info:
        dec.decode(raw)
    assert logic.field_code("control_modo", field_of(info.value)) == PanTiltError.REF_PAN_OUT_OF_RANGE
