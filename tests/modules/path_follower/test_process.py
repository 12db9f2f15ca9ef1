"""The path follower as a process on a real router: what reaches the DSP's mailbox, what goes on ERROR.

The DSP's telemetry is published by the test (the far end of the bus, at the DSP process's 20 Hz); the
commands are observed on the DSP process's mailbox key, so nothing here needs the DSP process.
"""

from __future__ import annotations

import functools
import math
import sys
from pathlib import Path

import msgspec
import pytest

from bbcs.slots import Kind, Safety
from bbcs.testing import stop_process

sys.path.insert(0, str(Path(__file__).resolve().parent))
from harness import (  # noqa: E402
    FOLLOWER_ROUTES,
    Source,
    TelemetryStream,
    Watch,
    close_rig,
    control_source,
    start_module,
)
from harness import step as marker_step  # noqa: E402

from bbcs.contracts import dsp as p  # noqa: E402
from bbcs.contracts.error_codes import FollowerError as E  # noqa: E402
from bbcs.contracts.path_follower import (  # noqa: E402
    ControlModoSegCam,
    DatoPuntoSegCam,
    DatosSegCam,
    HeadingSegCam,
    RefsSegCam,
    SpeedSegCam,
)

STOP_S = 20.0  # a loaded machine may take seconds to stop a Zenoh process: the exit code is what is checked
RF = {field: 0.0 for field in RefsSegCam.__struct_fields__}  # valid all-zero references
# per input, a datum refused at decoding and its code: the marker that ends a ``step`` (see ``harness.step``)
MARKERS = {
    "modo": ({"modo_o_comando": -1}, E.MODO_O_COMANDO_OUT_OF_RANGE),
    "heading": ({"heading": math.pi}, E.HEADING_OUT_OF_RANGE),
    "speed": ({"speed": -1e-9}, E.SPEED_OUT_OF_RANGE),
    "path": ({"n_points": 0, "puntos": []}, E.N_POINTS_OUT_OF_RANGE),
    "refs": ({**RF, "ref_rpm_motor": -1e-9}, E.REF_RPM_OUT_OF_RANGE),
}
PT = DatoPuntoSegCam(latitud=37.4118, longitud=-6.0024, altura=20.0)
step = functools.partial(marker_step, markers=MARKERS)


def mode(m: int) -> ControlModoSegCam:
    return ControlModoSegCam(modo_o_comando=0, modo_de_funcionamiento=m)


@pytest.fixture
def rig(processes, router, sessions, tmp_path):
    s = sessions()
    watch = Watch(s, "path_follower")
    proc = start_module(
        processes, router, tmp_path, "path_follower", "control_modo=1", "heading=2", "velocidad=3", "datos=4"
    )
    src = {
        "modo": Source(s, "gcs", "modo", ControlModoSegCam),
        "heading": Source(s, "gcs", "heading", HeadingSegCam, safety=Safety.UNSAFE),
        "speed": Source(s, "gcs", "speed", SpeedSegCam, safety=Safety.UNSAFE),
        "path": Source(s, "planner", "path", DatosSegCam, kind=Kind.STREAM),
        "refs": Source(s, "path_follower", "refs", RefsSegCam, safety=Safety.UNSAFE),
        "telemetry": TelemetryStream(
            s,
            p.Telemetry(
                time_ms=1,
                heading=45.0,
                status=p.DspStatus(mode=2, tracking=False, path_valid=False, airborne=False, queue_length=0),
            ),
        ),
        "control": control_source(s, "path_follower"),
    }
    try:
        watch.wait_alive()
        yield proc, watch, src
    finally:
        close_rig(watch, src)


def test_mode_table_and_slot_gating(rig):
    proc, watch, src = rig
    # ignored before any mode is known (DSP start-up mode semi-automatic): heading, path, refs
    step(watch, src, "speed", SpeedSegCam(speed=8.0), [p.SetSpeed(speed=8.0)], "speed always (at MAX_SPEED)")
    for name, value in [
        ("heading", HeadingSegCam(heading=1.0)),
        ("path", DatosSegCam(n_points=1, puntos=[PT])),
        (
            "refs",
            RefsSegCam(
                ref_altura=1, error_longitudinal=0, error_lateral=0, ref_heading=0, ref_rpm_motor=1500
            ),
        ),
    ]:
        step(watch, src, name, value, [], f"{name} ignored in mode 2")
    step(watch, src, "modo", mode(0), [p.SetMode(mode=p.Mode(0)), p.SetTracking(enable=True)], "mode 0")
    step(watch, src, "heading", HeadingSegCam(heading=1.0), [], "heading ignored in mode 0")
    step(
        watch,
        src,
        "path",
        DatosSegCam(n_points=2, puntos=[PT, PT]),
        [p.InvalidatePath(), *[p.AddWaypoint(lat=PT.latitud, lon=PT.longitud, alt=PT.altura)] * 2],
        "path in mode 0",
    )
    step(
        watch,
        src,
        "modo",
        mode(1),
        [
            p.SetHeading(heading_deg=pytest.approx(45.0)),
            p.SetMode(mode=p.Mode(1)),
            p.SetTracking(enable=True),
        ],
        "mode 1",
    )
    step(
        watch,
        src,
        "heading",
        HeadingSegCam(heading=-math.pi / 2),
        [p.SetHeading(heading_deg=-90.0)],
        "heading in degrees in mode 1",
    )
    step(
        watch,
        src,
        "path",
        DatosSegCam(n_points=1, puntos=[PT]),
        [p.InvalidatePath(), p.AddWaypoint(lat=PT.latitud, lon=PT.longitud, alt=PT.altura)],
        "path in mode 1",
    )
    step(
        watch,
        src,
        "modo",
        mode(2),
        [p.SetMode(mode=p.Mode(2)), p.SetTracking(enable=False), p.InvalidatePath()],
        "mode 2",
    )
    for m in (4, 5):
        step(
            watch,
            src,
            "modo",
            mode(m),
            [p.SetTracking(enable=False), p.InvalidatePath(), p.SetMode(mode=p.Mode(m))],
            f"mode {m}",
        )
    step(watch, src, "modo", mode(6), [p.SetMode(mode=p.Mode(6))], "mode 6")
    refs = RefsSegCam(
        ref_altura=30, error_longitudinal=2, error_lateral=-1, ref_heading=0.25, ref_rpm_motor=1500
    )
    set_refs = p.SetRefs(
        ref_altura=30, error_longitudinal=2, error_lateral=-1, ref_heading=0.25, ref_rpm_motor=1500
    )
    step(watch, src, "refs", refs, [set_refs], "refs as they are in mode 6")
    step(watch, src, "path", DatosSegCam(n_points=1, puntos=[PT]), [], "path ignored in mode 6")
    step(watch, src, "modo", ControlModoSegCam(modo_o_comando=1, numero_de_comando=0), [p.Abort()], "abort")
    step(watch, src, "modo", mode(3), [p.SetMode(mode=p.Mode(3)), p.InvalidatePath()],
         "mode 3: the onboard follower, the DSP queue emptied")
    step(watch, src, "refs", refs, [], "ground REFS ignored in mode 3 (the follower makes its own)")
    assert all(b.sender == "path_follower" for b in watch.batches)
    assert stop_process(proc, STOP_S) == 0


DP = {"latitud": 0.0, "longitud": 0.0, "altura": 0.0}
NEXT_BELOW_MINUS_PI = math.nextafter(-math.pi, -4)
BAD = [  # (source, raw datum, documented code): one per range bound of every struct
    ("modo", {"modo_o_comando": -1}, E.MODO_O_COMANDO_OUT_OF_RANGE),
    ("modo", {"modo_o_comando": 2}, E.MODO_O_COMANDO_OUT_OF_RANGE),
    ("modo", {"modo_o_comando": 0, "modo_de_funcionamiento": -1}, E.MODE_OUT_OF_RANGE),
    ("modo", {"modo_o_comando": 0, "modo_de_funcionamiento": 7}, E.MODE_OUT_OF_RANGE),
    ("modo", {"modo_o_comando": 1, "numero_de_comando": -1}, E.COMMAND_OUT_OF_RANGE),
    ("modo", {"modo_o_comando": 1, "numero_de_comando": 1}, E.COMMAND_OUT_OF_RANGE),
    ("heading", {"heading": NEXT_BELOW_MINUS_PI}, E.HEADING_OUT_OF_RANGE),
    ("heading", {"heading": math.pi}, E.HEADING_OUT_OF_RANGE),
    ("speed", {"speed": -1e-9}, E.SPEED_OUT_OF_RANGE),
    ("speed", {"speed": 8.0001}, E.SPEED_ABOVE_MAX),
    ("path", {"n_points": 0, "puntos": []}, E.N_POINTS_OUT_OF_RANGE),
    ("path", {"n_points": 2**32, "puntos": [DP]}, E.N_POINTS_OUT_OF_RANGE),
    ("path", {"n_points": 3, "puntos": [DP, DP]}, E.N_POINTS_MISMATCH),
    ("path", {"n_points": 2, "puntos": [DP, {**DP, "latitud": -90.001}]}, E.LATITUD_OUT_OF_RANGE),
    ("path", {"n_points": 2, "puntos": [DP, {**DP, "latitud": 90.001}]}, E.LATITUD_OUT_OF_RANGE),
    ("path", {"n_points": 2, "puntos": [{**DP, "longitud": -180.001}, DP]}, E.LONGITUD_OUT_OF_RANGE),
    ("path", {"n_points": 2, "puntos": [{**DP, "longitud": 180.001}, DP]}, E.LONGITUD_OUT_OF_RANGE),
    ("path", {"n_points": 1, "puntos": [{**DP, "altura": math.inf}]}, E.ALTURA_NOT_REPRESENTABLE),
    ("path", {"n_points": 513, "puntos": [DP] * 513}, E.PATH_TOO_LONG),
    ("refs", {**RF, "ref_heading": NEXT_BELOW_MINUS_PI}, E.REF_HEADING_OUT_OF_RANGE),
    ("refs", {**RF, "ref_heading": math.pi}, E.REF_HEADING_OUT_OF_RANGE),
    ("refs", {**RF, "ref_rpm_motor": -1e-9}, E.REF_RPM_OUT_OF_RANGE),
    ("refs", {**RF, "ref_rpm_motor": 1800.001}, E.REF_RPM_OUT_OF_RANGE),
    ("refs", {**RF, "ref_altura": math.nan}, E.REF_NOT_REPRESENTABLE),
    ("control", {"slot_entrada_datos": -2}, E.CONTROL_ENTRADA_OUT_OF_RANGE),
    ("modo", {"modo_o_comando": "uno"}, 2),  # not decodable: the bus's MALFORMED
]


def test_every_out_of_range_datum_gives_its_code_and_nothing_reaches_the_dsp(rig):
    proc, watch, src = rig
    step(watch, src, "modo", mode(0), [p.SetMode(mode=p.Mode(0)), p.SetTracking(enable=True)], "mode 0")
    # mode 0 accepts paths; mode 6 accepts refs: errors must not depend on the mode: refs tested in mode 6
    expected = list(watch.errors)  # the step's marker code
    for i, (name, raw, code) in enumerate(BAD):
        if name == "refs" and i and BAD[i - 1][0] != "refs":
            step(watch, src, "modo", mode(6), [p.SetMode(mode=p.Mode(6))], "mode 6 for refs")
            expected.append(MARKERS["modo"][1])
        before, n = len(watch.commands()), len(watch.errors)
        src[name].send_raw(msgspec.msgpack.encode(raw))
        watch.wait_for(lambda n=n: len(watch.errors) > n, f"error code for {name} {raw}")
        expected.append(code)
        assert watch.errors[n] == code, (name, raw)
        assert len(watch.commands()) == before, f"{name} {raw} reached the DSP"
    # the last bad datum once more on its input: its code proves no further code of the earlier ones is coming
    name, raw, code = BAD[-1]
    src[name].send_raw(msgspec.msgpack.encode(raw))
    watch.wait_for(lambda: len(watch.errors) > len(expected), "the closing marker's code")
    assert watch.errors == [*expected, code]
    # the bad CONTROL_ENTRADA left the routes in force: the planner's path still arrives (back in mode 0)
    step(watch, src, "modo", mode(0), [p.SetMode(mode=p.Mode(0)), p.SetTracking(enable=True)], "mode 0 again")
    step(
        watch,
        src,
        "path",
        DatosSegCam(n_points=1, puntos=[PT]),
        [p.InvalidatePath(), p.AddWaypoint(lat=PT.latitud, lon=PT.longitud, alt=PT.altura)],
        "routes kept",
    )
    assert not [a for a in watch.acks if not a.accepted]
    assert stop_process(proc, STOP_S) == 0


def test_minus_one_ignores_an_input(rig):
    proc, watch, src = rig
    step(watch, src, "modo", mode(0), [p.SetMode(mode=p.Mode(0)), p.SetTracking(enable=True)], "mode 0")
    src["control"].send(msgspec.structs.replace(FOLLOWER_ROUTES, slot_entrada_datos=-1))
    watch.wait_for(lambda: bool(watch.acks) and watch.acks[-1].routes.get("datos") == -1, "datos ignored")
    step(watch, src, "path", DatosSegCam(n_points=1, puntos=[PT]), [], "-1 ignores the planner's path", via="modo")
    step(watch, src, "speed", SpeedSegCam(speed=1.0), [p.SetSpeed(speed=1.0)], "other inputs still routed")
    assert stop_process(proc, STOP_S) == 0
