"""Path follower decisions: each row of SPEC §3.3's table, HEADING/VELOCIDAD/DATOS/REFS, every range bound."""

from __future__ import annotations

import math

import msgspec
import pytest

from bbcs.codec import field_of
from bbcs.contracts import dsp as p
from bbcs.contracts.dsp import DspErrorReport, LinkErrorCode
from bbcs.contracts.error_codes import FollowerError
from bbcs.contracts.path_follower import (
    ControlEntradaSegCam,
    ControlModoSegCam,
    DatoPuntoSegCam,
    DatosSegCam,
    HeadingSegCam,
    RefsSegCam,
    SpeedSegCam,
)
from modules.path_follower import logic
from modules.path_follower.logic import FollowerState

PT = DatoPuntoSegCam(latitud=37.4118, longitud=-6.0024, altura=20.0)
REFS = RefsSegCam(
    ref_altura=20.0, error_longitudinal=1.0, error_lateral=-1.0, ref_heading=0.5, ref_rpm_motor=1500
)


def mode(m: int) -> ControlModoSegCam:
    return ControlModoSegCam(modo_o_comando=0, modo_de_funcionamiento=m)


def path(n: int) -> DatosSegCam:
    return DatosSegCam(n_points=n, puntos=[PT] * n)


def test_abort_empties_both_queues():
    s = FollowerState(mode=0, path=(PT, PT))
    d = logic.on_control_modo(s, ControlModoSegCam(modo_o_comando=1, numero_de_comando=0))
    assert d.commands == (p.Abort(),) and d.errors == ()
    assert d.state.path == () and d.state.mode == 0


def test_mode_0_sets_mode_and_enables_tracking():
    d = logic.on_control_modo(FollowerState(), mode(0))
    assert d.commands == (p.SetMode(mode=p.Mode.PATH_AUTO_HEADING), p.SetTracking(enable=True))
    assert d.state.mode == 0


def test_mode_1_sends_current_heading_with_mode_and_enables_tracking():
    d = logic.on_control_modo(FollowerState(heading_deg=123.5), mode(1))
    assert d.commands == (
        p.SetHeading(heading_deg=pytest.approx(123.5)),
        p.SetMode(mode=p.Mode.PATH_GIVEN_HEADING),
        p.SetTracking(enable=True),
    )
    assert d.state.mode == 1


def test_mode_1_without_a_known_heading_is_refused():
    s = FollowerState(mode=0)
    d = logic.on_control_modo(s, mode(1))
    assert d.commands == () and d.errors == (FollowerError.HEADING_UNKNOWN,) and d.state == s


def test_mode_2_disables_tracking_and_invalidates():
    d = logic.on_control_modo(FollowerState(mode=0, path=(PT,)), mode(2))
    assert d.commands == (
        p.SetMode(mode=p.Mode.SEMI_AUTOMATIC),
        p.SetTracking(enable=False),
        p.InvalidatePath(),
    )
    assert d.state.path == ()


def test_mode_3_sets_the_onboard_follower_mode_and_empties_both_the_onboard_trajectory_and_the_dsps_queue():
    d = logic.on_control_modo(FollowerState(mode=0, path=(PT,)), mode(3))
    assert d.commands == (p.SetMode(mode=p.Mode.ONBOARD_FOLLOWER), p.InvalidatePath()) and d.errors == ()
    assert d.state.mode == 3 and d.state.path == ()


@pytest.mark.parametrize("m", [4, 5])
def test_take_off_and_landing(m):
    d = logic.on_control_modo(FollowerState(mode=0, path=(PT,)), mode(m))
    assert d.commands == (p.SetTracking(enable=False), p.InvalidatePath(), p.SetMode(mode=p.Mode(m)))
    assert d.state.mode == m and d.state.path == ()


def test_mode_6_bridge():
    d = logic.on_control_modo(FollowerState(), mode(6))
    assert d.commands == (p.SetMode(mode=p.Mode.BRIDGE),)


def test_heading_only_in_mode_1_in_degrees():
    for m in (None, 0, 2, 3, 4, 5, 6):
        assert logic.on_heading(FollowerState(mode=m), HeadingSegCam(heading=1.0)).commands == ()
    d = logic.on_heading(FollowerState(mode=1), HeadingSegCam(heading=-math.pi / 2))
    assert d.commands == (p.SetHeading(heading_deg=-90.0),)
    assert (
        logic.on_heading(FollowerState(mode=1), HeadingSegCam(heading=-math.pi)).commands[0].heading_deg
        == -180
    )


@pytest.mark.parametrize("m", [None, 0, 1, 2, 4, 5, 6])
def test_speed_always_sent(m):
    d = logic.on_velocidad(FollowerState(mode=m), SpeedSegCam(speed=8.0), max_speed=8.0)
    assert d.commands == (p.SetSpeed(speed=8.0),)


@pytest.mark.parametrize("speed", [8.0001, math.inf])
def test_speed_above_max_refused(speed):
    d = logic.on_velocidad(FollowerState(mode=0), SpeedSegCam(speed=speed), max_speed=8.0)
    assert d.commands == () and d.errors == (FollowerError.SPEED_ABOVE_MAX,)


@pytest.mark.parametrize("m", [0, 1])
def test_datos_in_modes_0_and_1_sends_every_waypoint(m):
    pts = [DatoPuntoSegCam(latitud=37.0 + i / 1e4, longitud=-6.0, altura=10.0 + i) for i in range(3)]
    d = logic.on_datos(FollowerState(mode=m), DatosSegCam(n_points=3, puntos=pts))
    assert d.commands == (p.InvalidatePath(),) + tuple(
        p.AddWaypoint(lat=q.latitud, lon=q.longitud, alt=q.altura) for q in pts
    )
    assert d.state.path == tuple(pts)


def test_a_new_path_replaces_the_old_one_in_both_queues():
    old = [DatoPuntoSegCam(latitud=37.0 + i / 1e4, longitud=-6.0, altura=20.0) for i in range(6)]
    new = [DatoPuntoSegCam(latitud=38.0 + i / 1e4, longitud=-6.0, altura=20.0) for i in range(2)]
    first = logic.on_datos(FollowerState(mode=0), DatosSegCam(n_points=6, puntos=old))
    d = logic.on_datos(first.state, DatosSegCam(n_points=2, puntos=new))
    assert d.commands[0] == p.InvalidatePath(), "the DSP's queue is emptied before the new path's first waypoint"
    assert d.commands[1:] == tuple(p.AddWaypoint(lat=q.latitud, lon=q.longitud, alt=q.altura) for q in new)
    assert d.state.path == tuple(new), "the onboard queue holds only the new path"


@pytest.mark.parametrize("m", [None, 2, 4, 5, 6])
def test_datos_ignored_in_other_modes(m):
    d = logic.on_datos(FollowerState(mode=m), path(2))
    assert d.commands == () and d.errors == ()


@pytest.mark.parametrize("n,count", [(3, 2), (1, 2), (2, 0)])
def test_datos_count_mismatch_rejects_the_whole_message(n, count):
    d = logic.on_datos(FollowerState(mode=0), DatosSegCam(n_points=n, puntos=[PT] * count))
    assert d.commands == () and d.errors == (FollowerError.N_POINTS_MISMATCH,)


def test_datos_one_bad_altitude_rejects_the_whole_message():
    pts = [PT, DatoPuntoSegCam(latitud=1.0, longitud=1.0, altura=math.nan), PT]
    d = logic.on_datos(FollowerState(mode=0), DatosSegCam(n_points=3, puntos=pts))
    assert d.commands == () and d.errors == (FollowerError.ALTURA_NOT_REPRESENTABLE,)


def test_datos_longer_than_the_dsp_queue_is_refused():
    assert len(logic.on_datos(FollowerState(mode=0), path(512)).commands) == 1 + 512
    d = logic.on_datos(FollowerState(mode=0), path(513))
    assert d.commands == () and d.errors == (FollowerError.PATH_TOO_LONG,)


def test_refs_only_in_mode_6_as_they_are():
    for m in (None, 0, 1, 2, 3, 4, 5):
        assert logic.on_refs(FollowerState(mode=m), REFS).commands == ()
    d = logic.on_refs(FollowerState(mode=6), REFS)
    assert d.commands == (
        p.SetRefs(
            ref_altura=20.0, error_longitudinal=1.0, error_lateral=-1.0, ref_heading=0.5, ref_rpm_motor=1500.0
        ),
    )


@pytest.mark.parametrize("field", ["ref_altura", "error_longitudinal", "error_lateral"])
def test_refs_not_representable(field):
    d = logic.on_refs(FollowerState(mode=6), msgspec.structs.replace(REFS, **{field: math.inf}))
    assert d.commands == () and d.errors == (FollowerError.REF_NOT_REPRESENTABLE,)


def test_telemetry_gives_heading_and_mode_until_commanded():
    t = p.Telemetry(
        time_ms=0,
        heading=42.0,
        status=p.DspStatus(mode=0, tracking=True, path_valid=True, airborne=True, queue_length=3),
    )
    s = logic.on_telemetry(FollowerState(), t)
    assert s.heading_deg == 42.0 and s.mode == 0
    s = logic.on_control_modo(s, mode(6)).state
    assert logic.on_telemetry(s, t).mode == 6


def test_dsp_errors_forwarded_and_refused_mode_undone():
    s = FollowerState(mode=6, mode_from_command=True)
    own = DspErrorReport(code=3, name="NOT_CONFIGURED", detail="", sender="path_follower", batch_id=7)
    d = logic.on_dsp_error(s, own, "path_follower", restore_mode=True, mode_before=2)
    assert d.errors == (1003,) and d.state.mode == 2
    fault = DspErrorReport(code=int(p.ErrorCode.GPS_LOST), name="GPS_LOST", detail="")
    assert logic.on_dsp_error(s, fault, "path_follower").errors == (1006,)
    rx = DspErrorReport(code=int(p.ErrorCode.RX_ERRORS), name="RX_ERRORS", detail="")
    assert logic.on_dsp_error(s, rx, "path_follower").errors == ()
    other = DspErrorReport(code=2, name="WRONG_MODE", detail="", sender="pan_tilt")
    assert logic.on_dsp_error(s, other, "path_follower").errors == ()


def test_a_refused_telemetry_frame_is_no_dsp_fault_but_the_dsps_own_sensor_fault_is() -> None:
    """Issue 30 case 3: 1009 is the DSP's own SENSOR_FAULT (an IMU failure it reports in an ERROR message), forwarded
    because it stops ordered tasks. A telemetry frame the DSP process refused is not a DSP fault: it is reported on
    the DSP process's ERROR slot only (TELEMETRY_REFUSED), and were it ever on ``dsp/errors`` it would not be
    forwarded."""
    s = FollowerState(mode=0, mode_from_command=True)
    sensor = DspErrorReport(code=int(p.ErrorCode.SENSOR_FAULT), name="SENSOR_FAULT", detail="the DSP reported it")
    assert logic.on_dsp_error(s, sensor, "path_follower").errors == (1009,)
    refused = DspErrorReport(code=int(LinkErrorCode.TELEMETRY_REFUSED), name="TELEMETRY_REFUSED",
                             detail="Telemetry.position.lat=200.0 is out of range [-90.0, 90.0]")
    decision = logic.on_dsp_error(s, refused, "path_follower")
    assert decision.errors == () and decision.commands == () and decision.state == s


# every range bound: (slot, struct, base, field path, in-range bound, just outside, code)
DP = {"latitud": 0.0, "longitud": 0.0, "altura": 0.0}
CM = {"modo_o_comando": 0}
RF = {
    "ref_altura": 0.0,
    "error_longitudinal": 0.0,
    "error_lateral": 0.0,
    "ref_heading": 0.0,
    "ref_rpm_motor": 0.0,
}
E = FollowerError
BOUNDS = [
    *[
        ("control_entrada", ControlEntradaSegCam, {}, f, -1, -2, E.CONTROL_ENTRADA_OUT_OF_RANGE)
        for f in (
            "slot_entrada_control_modos",
            "slot_entrada_heading",
            "slot_entrada_speed",
            "slot_entrada_datos",
        )
    ],
    ("control_modo", ControlModoSegCam, CM, "modo_o_comando", 0, -1, E.MODO_O_COMANDO_OUT_OF_RANGE),
    ("control_modo", ControlModoSegCam, CM, "modo_o_comando", 1, 2, E.MODO_O_COMANDO_OUT_OF_RANGE),
    ("control_modo", ControlModoSegCam, CM, "modo_de_funcionamiento", 0, -1, E.MODE_OUT_OF_RANGE),
    ("control_modo", ControlModoSegCam, CM, "modo_de_funcionamiento", 6, 7, E.MODE_OUT_OF_RANGE),
    ("control_modo", ControlModoSegCam, CM, "numero_de_comando", 0, -1, E.COMMAND_OUT_OF_RANGE),
    ("control_modo", ControlModoSegCam, CM, "numero_de_comando", 0, 1, E.COMMAND_OUT_OF_RANGE),
    ("heading", HeadingSegCam, {}, "heading", -math.pi, math.nextafter(-math.pi, -4), E.HEADING_OUT_OF_RANGE),
    ("heading", HeadingSegCam, {}, "heading", math.nextafter(math.pi, 0), math.pi, E.HEADING_OUT_OF_RANGE),
    ("velocidad", SpeedSegCam, {}, "speed", 0.0, -1e-9, E.SPEED_OUT_OF_RANGE),
    ("datos", DatosSegCam, {"puntos": [DP]}, "n_points", 1, 0, E.N_POINTS_OUT_OF_RANGE),
    ("datos", DatosSegCam, {"puntos": [DP]}, "n_points", 2**32 - 1, 2**32, E.N_POINTS_OUT_OF_RANGE),
    (
        "refs",
        RefsSegCam,
        RF,
        "ref_heading",
        -math.pi,
        math.nextafter(-math.pi, -4),
        E.REF_HEADING_OUT_OF_RANGE,
    ),
    ("refs", RefsSegCam, RF, "ref_heading", math.nextafter(math.pi, 0), math.pi, E.REF_HEADING_OUT_OF_RANGE),
    ("refs", RefsSegCam, RF, "ref_rpm_motor", 0.0, -1e-9, E.REF_RPM_OUT_OF_RANGE),
    ("refs", RefsSegCam, RF, "ref_rpm_motor", 1800.0, 1800.001, E.REF_RPM_OUT_OF_RANGE),
]
POINT_BOUNDS = [
    ("latitud", -90.0, -90.001, E.LATITUD_OUT_OF_RANGE),
    ("latitud", 90.0, 90.001, E.LATITUD_OUT_OF_RANGE),
    ("longitud", -180.0, -180.001, E.LONGITUD_OUT_OF_RANGE),
    ("longitud", 180.0, 180.001, E.LONGITUD_OUT_OF_RANGE),
]


@pytest.mark.parametrize("slot,typ,base,field,inside,outside,code", BOUNDS)
def test_every_range_bound(slot, typ, base, field, inside, outside, code):
    dec = msgspec.msgpack.Decoder(typ)
    assert getattr(dec.decode(msgspec.msgpack.encode({**base, field: inside})), field) == inside
    with pytest.raises(msgspec.ValidationError) as info:
        dec.decode(msgspec.msgpack.encode({**base, field: outside}))
    assert logic.field_code(slot, field_of(info.value)) == code


@pytest.mark.parametrize("field,inside,outside,code", POINT_BOUNDS)
def test_every_waypoint_bound_in_any_point_rejects_the_whole_message(field, inside, outside, code):
    dec = msgspec.msgpack.Decoder(DatosSegCam)
    good = dec.decode(msgspec.msgpack.encode({"n_points": 3, "puntos": [DP, {**DP, field: inside}, DP]}))
    assert getattr(good.puntos[1], field) == inside
    with pytest.raises(msgspec.ValidationError) as info:
        dec.decode(msgspec.msgpack.encode({"n_points": 3, "puntos": [DP, {**DP, field: outside}, DP]}))
    assert field_of(info.value) == f"$.puntos[1].{field}"
    assert logic.field_code("datos", field_of(info.value)) == code


def carrying(m: int, **data) -> ControlModoSegCam:  # type: ignore[no-untyped-def]
    return ControlModoSegCam(modo_o_comando=0, modo_de_funcionamiento=m, **data)


def test_a_mode_carrying_its_tasks_data_sends_the_mode_then_speed_heading_and_path():
    """The four-hop path (docs/bus.md): one message; the mode as its own batch, then the data under it, the speed
    before the path so its first waypoint is flown at it."""
    msg = carrying(1, velocidad=SpeedSegCam(speed=4.0), heading=HeadingSegCam(heading=-math.pi / 2), datos=path(2))
    mode_d, data_d = logic.on_mode_message(FollowerState(heading_deg=10.0), msg, max_speed=8.0)
    assert mode_d.commands == (p.SetHeading(heading_deg=pytest.approx(10.0)), p.SetMode(mode=p.Mode.PATH_GIVEN_HEADING),
                               p.SetTracking(enable=True))
    assert data_d.commands == (p.SetSpeed(speed=4.0), p.SetHeading(heading_deg=-90.0), p.InvalidatePath(),
                               p.AddWaypoint(lat=PT.latitud, lon=PT.longitud, alt=PT.altura),
                               p.AddWaypoint(lat=PT.latitud, lon=PT.longitud, alt=PT.altura))
    assert data_d.state.mode == 1 and data_d.state.path == (PT, PT) and mode_d.errors == data_d.errors == ()


def test_a_mode_alone_sends_no_data():
    mode_d, data_d = logic.on_mode_message(FollowerState(), mode(0), max_speed=8.0)
    assert mode_d == logic.on_control_modo(FollowerState(), mode(0)) and data_d.commands == ()


@pytest.mark.parametrize("msg,code", [
    (carrying(0, velocidad=SpeedSegCam(speed=9.0), datos=path(1)), FollowerError.SPEED_ABOVE_MAX),
    (carrying(0, velocidad=SpeedSegCam(speed=4.0), datos=path(logic.p.WAYPOINT_QUEUE_CAPACITY + 1)),
     FollowerError.PATH_TOO_LONG),
    (carrying(0, datos=DatosSegCam(n_points=2, puntos=[PT])), FollowerError.N_POINTS_MISMATCH),
])
def test_a_bad_carried_datum_refuses_the_whole_message_and_changes_nothing(msg, code):
    before = FollowerState(mode=5, path=(PT,))
    mode_d, data_d = logic.on_mode_message(before, msg, max_speed=8.0)
    assert mode_d.errors == (code,) and mode_d.commands == () and data_d.commands == ()
    assert mode_d.state == before == data_d.state, "the mode is kept: the module answers refused"


def test_a_carried_path_in_mode_3_is_kept_onboard_not_queued_on_the_dsp():
    mode_d, data_d = logic.on_mode_message(FollowerState(), carrying(3, velocidad=SpeedSegCam(speed=4.0),
                                                                      datos=path(2)), max_speed=8.0)
    assert mode_d.commands == (p.SetMode(mode=p.Mode.ONBOARD_FOLLOWER), p.InvalidatePath())
    assert data_d.commands == (p.SetSpeed(speed=4.0),) and data_d.state.path == (PT, PT)


def test_a_carried_datums_range_error_has_its_own_code():
    dec = msgspec.msgpack.Decoder(ControlModoSegCam)
    raw = msgspec.msgpack.encode({"modo_o_comando": 0, "velocidad": {"speed": -1.0}})
    with pytest.raises(msgspec.ValidationError) as info:
        dec.decode(raw)
    assert logic.field_code("control_modo", field_of(info.value)) == FollowerError.SPEED_OUT_OF_RANGE
