"""The pan & tilt module as a process on a real router: routing between two DATOS sources at run time, -1,
the mode table and every out-of-range datum (its code on ERROR, nothing to the DSP's command mailbox)."""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import msgspec
import pytest

from bbcs.slots import Safety
from bbcs.testing import stop_process

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "path_follower"))
from harness import Source, Watch, close_rig, control_source, start_module  # noqa: E402
from harness import step as marker_step  # noqa: E402

from bbcs.contracts import dsp as p  # noqa: E402
from bbcs.contracts.error_codes import PanTiltError as E  # noqa: E402
from bbcs.contracts.pan_tilt import ControlEntradaPT, DatosPT, ModoFuncionamientoPT  # noqa: E402

STOP_S = 20.0  # a loaded machine may take seconds to stop a Zenoh process: the exit code is what is checked
# per input, a datum refused at decoding and its code: the marker that ends a ``step`` (see ``harness.step``)
MARKERS = {
    "modo": ({"modo_de_funcionamiento": 3}, E.MODE_OUT_OF_RANGE),
    "a": ({"ref_pan": 180.001}, E.REF_PAN_OUT_OF_RANGE),
    "b": ({"ref_pan": 180.001}, E.REF_PAN_OUT_OF_RANGE),
}
step = functools.partial(marker_step, markers=MARKERS)


@pytest.fixture
def rig(processes, router, sessions, tmp_path):
    s = sessions()
    watch = Watch(s, "pan_tilt")
    proc = start_module(processes, router, tmp_path, "pan_tilt", "control_modo=10", "datos=11")
    src = {
        "modo": Source(s, "gcs", "pt_modo", ModoFuncionamientoPT),
        "a": Source(s, "vision_a", "datos_pt", DatosPT, safety=Safety.UNSAFE),
        "b": Source(s, "vision_b", "datos_pt", DatosPT, safety=Safety.UNSAFE),
        "control": control_source(s, "pan_tilt"),
    }
    try:
        watch.wait_alive()
        yield proc, watch, src
    finally:
        close_rig(watch, src)


def angles(pan: float, tilt: float = 0.0) -> DatosPT:
    return DatosPT(ref_pan=pan, ref_tilt=tilt)


def test_modes_and_routing_between_two_sources(rig):
    proc, watch, src = rig
    step(watch, src, "a", angles(10), [], "mode unknown (DSP start-up: hold): nothing")
    step(
        watch,
        src,
        "modo",
        ModoFuncionamientoPT(modo_de_funcionamiento=0),
        [p.SetPanTiltMode(mode=p.PanTiltMode.ANGLES)],
        "mode 0 as it is",
    )
    step(watch, src, "a", angles(11, -5), [p.SetPanTiltAngles(pan_deg=11, tilt_deg=-5)], "A drives in mode 0")
    step(watch, src, "b", angles(99), [], "B is not selected", via="modo")
    src["control"].send(ControlEntradaPT(slot_entrada_control_modos=10, slot_entrada_datos=12))
    watch.wait_for(
        lambda: bool(watch.acks) and watch.acks[-1].routes == {"control_modo": 10, "datos": 12}, "switch to B"
    )
    step(watch, src, "a", angles(12), [], "A no longer selected", via="modo")
    step(watch, src, "b", angles(-120, 45), [p.SetPanTiltAngles(pan_deg=-120, tilt_deg=45)], "B drives")
    step(
        watch,
        src,
        "modo",
        ModoFuncionamientoPT(modo_de_funcionamiento=1),
        [p.SetPanTiltMode(mode=p.PanTiltMode.TARGET)],
        "mode 1",
    )
    step(
        watch,
        src,
        "b",
        DatosPT(latitud=37.5, longitud=-6.1, altura=30.0),
        [p.SetPanTiltTarget(lat=37.5, lon=-6.1, alt=30.0)],
        "target point in mode 1",
    )
    step(
        watch,
        src,
        "modo",
        ModoFuncionamientoPT(modo_de_funcionamiento=2),
        [p.SetPanTiltMode(mode=p.PanTiltMode.HOLD)],
        "mode 2",
    )
    step(watch, src, "b", angles(5), [], "mode 2: nothing")
    src["control"].send(ControlEntradaPT(slot_entrada_control_modos=10, slot_entrada_datos=-1))
    watch.wait_for(lambda: watch.acks[-1].routes == {"control_modo": 10, "datos": -1}, "ignore DATOS")
    step(
        watch,
        src,
        "modo",
        ModoFuncionamientoPT(modo_de_funcionamiento=0),
        [p.SetPanTiltMode(mode=p.PanTiltMode.ANGLES)],
        "mode 0 again",
    )
    step(watch, src, "a", angles(1), [], "-1: A ignored", via="modo")
    step(watch, src, "b", angles(2), [], "-1: B ignored", via="modo")
    # a route to an unknown slot is refused and the old routes stay
    src["control"].send(ControlEntradaPT(slot_entrada_control_modos=10, slot_entrada_datos=77))
    watch.wait_for(lambda: not watch.acks[-1].accepted, "refused route")
    assert watch.errors[-1] == 3 and watch.acks[-1].routes == {"control_modo": 10, "datos": -1}
    assert stop_process(proc, STOP_S) == 0


BAD = [
    ("modo", {"modo_de_funcionamiento": -1}, E.MODE_OUT_OF_RANGE),
    ("modo", {"modo_de_funcionamiento": 3}, E.MODE_OUT_OF_RANGE),
    ("a", {"ref_pan": -180.001}, E.REF_PAN_OUT_OF_RANGE),
    ("a", {"ref_pan": 180.001}, E.REF_PAN_OUT_OF_RANGE),
    ("a", {"ref_tilt": -90.001}, E.REF_TILT_OUT_OF_RANGE),
    ("a", {"ref_tilt": 90.001}, E.REF_TILT_OUT_OF_RANGE),
    ("a", {"latitud": -90.001}, E.LATITUD_OUT_OF_RANGE),
    ("a", {"latitud": 90.001}, E.LATITUD_OUT_OF_RANGE),
    ("a", {"longitud": -180.001}, E.LONGITUD_OUT_OF_RANGE),
    ("a", {"longitud": 180.001}, E.LONGITUD_OUT_OF_RANGE),
    ("control", {"slot_entrada_control_modos": -2}, E.CONTROL_ENTRADA_OUT_OF_RANGE),
    ("control", {"slot_entrada_datos": -2}, E.CONTROL_ENTRADA_OUT_OF_RANGE),
]


@pytest.mark.parametrize("target_mode", [0, 1])
def test_every_out_of_range_datum(rig, target_mode):
    proc, watch, src = rig
    step(
        watch,
        src,
        "modo",
        ModoFuncionamientoPT(modo_de_funcionamiento=target_mode),
        [p.SetPanTiltMode(mode=p.PanTiltMode(target_mode))],
        f"mode {target_mode}",
    )
    bad = [*BAD, *([("a", {"altura": float("inf")}, E.ALTURA_NOT_REPRESENTABLE)] if target_mode == 1 else [])]
    expected = list(watch.errors)  # the step's marker code
    for name, raw, code in bad:
        before, n = len(watch.commands()), len(watch.errors)
        src[name].send_raw(msgspec.msgpack.encode(raw))
        watch.wait_for(lambda n=n: len(watch.errors) > n, f"error code for {raw}")
        expected.append(code)
        assert watch.errors[n] == code, raw
        assert len(watch.commands()) == before, f"{raw} reached the DSP"
    # the last bad datum once more on its input: its code proves no further code of the earlier ones is coming
    name, raw, code = bad[-1]
    src[name].send_raw(msgspec.msgpack.encode(raw))
    watch.wait_for(lambda: len(watch.errors) > len(expected), "the closing marker's code")
    assert watch.errors == [*expected, code]
    assert [a.accepted for a in watch.acks] == [True] * len(watch.acks)
    assert stop_process(proc, STOP_S) == 0
