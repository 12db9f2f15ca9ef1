"""Pan & tilt end to end (SPEC §3.2): its modes, its DATOS switched between two sources at run time, -1, and
out-of-range data — from the bus through the pan & tilt process and the DSP process to the simulated DSP."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from bbcs.contracts import dsp as p
from bbcs.contracts.error_codes import PanTiltError as E
from bbcs.contracts.pan_tilt import ControlEntradaPT, DatosPT, ModoFuncionamientoPT

from .uav_stack import DEADLINE_S, SLOT, Stack, wait_until

PT = "pan_tilt"
TARGET = DatosPT(latitud=37.4127, longitud=-6.0015, altura=5.0)


def routes(datos: int) -> tuple[ControlEntradaPT, dict[str, int]]:
    return (
        ControlEntradaPT(slot_entrada_control_modos=SLOT["pt_modo"], slot_entrada_datos=datos),
        {"control_modo": SLOT["pt_modo"], "datos": datos},
    )


def angles(pan: float, tilt: float) -> DatosPT:
    return DatosPT(ref_pan=pan, ref_tilt=tilt)


@pytest.fixture(scope="module")
def uav(tmp_path_factory) -> Iterator[Stack]:
    stack = Stack(tmp_path_factory.mktemp("uav_routing"), [PT])
    try:
        yield stack.start()
    finally:
        stack.close()


def enter(stack: Stack, m: int) -> None:
    mark = stack.mark()
    stack.send("pt_modo", ModoFuncionamientoPT(modo_de_funcionamiento=m))
    stack.expect(mark, [p.SetPanTiltMode(mode=p.PanTiltMode(m))], f"pan & tilt mode {m}")
    stack.wait_telemetry(
        lambda t: t.pan_tilt is not None and t.pan_tilt.mode == m, f"DSP pan & tilt mode {m}"
    )


@pytest.fixture
def stack(uav: Stack) -> Stack:
    """Every test starts with DATOS read from the ground station's slot, in mode 0 (angles)."""
    uav.route(PT, *routes(SLOT["pt_gcs"]))
    enter(uav, 0)
    return uav


def pan_reaches(stack: Stack, pan: float, tilt: float, what: str) -> None:
    """The simulated pan & tilt unit turns to the references (telemetry), so they drive the DSP."""
    stack.wait_telemetry(
        lambda t: abs(t.pan_tilt.pan - pan) < 0.5 and abs(t.pan_tilt.tilt - tilt) < 0.5, what
    )


def test_modes_and_what_datos_sends_in_each(stack: Stack) -> None:
    mark = stack.mark()
    stack.send("pt_gcs", angles(25.0, -10.0))
    stack.expect(mark, [p.SetPanTiltAngles(pan_deg=25.0, tilt_deg=-10.0)], "angles in mode 0")
    pan_reaches(stack, 25.0, -10.0, "pan & tilt at the angle references")
    enter(stack, 1)
    mark = stack.mark()
    stack.send("pt_gcs", TARGET)
    stack.expect(
        mark,
        [p.SetPanTiltTarget(lat=TARGET.latitud, lon=TARGET.longitud, alt=TARGET.altura)],
        "target point in mode 1",
    )
    enter(stack, 2)
    mark = stack.mark()
    stack.send("pt_gcs", angles(-40.0, 30.0))
    stack.handled(PT, "pt_gcs", {"ref_pan": 180.5}, E.REF_PAN_OUT_OF_RANGE, "DATOS in mode 2")
    stack.barrier()
    assert stack.received(mark) == [], "DATOS reached the DSP in mode 2 (hold)"
    assert not [r for r in stack.reports if r.sender == PT], "the DSP refused a pan & tilt command"


def test_datos_switched_between_two_sources_only_the_selected_one_drives_the_dsp(stack: Stack) -> None:
    for selected, other, pan in (
        ("pt_gcs", "pt_vision", 12.0),
        ("pt_vision", "pt_gcs", -33.0),
        ("pt_gcs", "pt_vision", 45.0),
    ):
        stack.route(PT, *routes(SLOT[selected]))
        mark = stack.mark()
        stack.send(other, angles(-pan, 60.0))  # first: if it were read, its command would come first
        stack.send(selected, angles(pan, -20.0))
        stack.expect(
            mark, [p.SetPanTiltAngles(pan_deg=pan, tilt_deg=-20.0)], f"only {selected} drives the DSP"
        )
        pan_reaches(stack, pan, -20.0, f"pan & tilt following {selected}")


def test_minus_one_ignores_the_input(stack: Stack) -> None:
    stack.route(PT, *routes(-1))
    errors = stack.error_mark(PT)
    mark = stack.mark()
    stack.send("pt_gcs", angles(70.0, 10.0))
    stack.send("pt_vision", angles(-70.0, 10.0))
    stack.send_raw("pt_gcs", {"ref_pan": 500.0})  # not even read: no error code either
    stack.route(PT, *routes(SLOT["pt_gcs"]))
    stack.send("pt_gcs", angles(5.0, 5.0))
    # anything read while DATOS was ignored would have reached the DSP before this datum
    stack.expect(mark, [p.SetPanTiltAngles(pan_deg=5.0, tilt_deg=5.0)], "nothing while DATOS was -1")
    assert stack.error_mark(PT) == errors


def test_bad_control_entrada_is_refused_and_the_routes_stay(stack: Stack) -> None:
    errors = stack.error_mark(PT)
    stack.send_raw("pt_control", {"slot_entrada_control_modos": SLOT["pt_modo"], "slot_entrada_datos": -2})
    stack.expect_error(PT, errors, E.CONTROL_ENTRADA_OUT_OF_RANGE, "CONTROL_ENTRADA_PT slot -2")
    mark = stack.mark()
    stack.send("pt_vision", angles(-15.0, 0.0))
    stack.send("pt_gcs", angles(15.0, 0.0))
    stack.expect(mark, [p.SetPanTiltAngles(pan_deg=15.0, tilt_deg=0.0)], "the ground station still selected")


BAD = [  # (input, raw datum, code, mode in which a good datum would reach the DSP)
    ("pt_modo", {"modo_de_funcionamiento": 3}, E.MODE_OUT_OF_RANGE, 0),
    ("pt_gcs", {"ref_pan": -180.5}, E.REF_PAN_OUT_OF_RANGE, 0),
    ("pt_gcs", {"ref_tilt": 90.5}, E.REF_TILT_OUT_OF_RANGE, 0),
    ("pt_gcs", {"latitud": -90.5}, E.LATITUD_OUT_OF_RANGE, 1),
    ("pt_gcs", {"longitud": 180.5}, E.LONGITUD_OUT_OF_RANGE, 1),
    ("pt_gcs", {"altura": 1e39}, E.ALTURA_NOT_REPRESENTABLE, 1),
]


@pytest.mark.parametrize(("source", "raw", "code", "m"), BAD, ids=[f"{b[0]}-{int(b[2])}" for b in BAD])
def test_out_of_range_datum_gives_its_code_and_nothing_reaches_the_dsp(
    stack: Stack, source, raw, code, m
) -> None:
    if m:
        enter(stack, m)
    stack.refused(PT, source, raw, code)
    wait_until(lambda: stack.latest().pan_tilt.mode == m, DEADLINE_S, "pan & tilt mode unchanged")
