"""SPEC §3.3 end to end: every row of the mode/command table, slot gating by mode and out-of-range data, from
the bus through the path follower and the DSP process to the simulated DSP on a pty, and back as telemetry."""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest

from bbcs.contracts import dsp as p
from bbcs.contracts.error_codes import FollowerError as E
from bbcs.contracts.path_follower import (
    ControlEntradaSegCam,
    ControlModoSegCam,
    DatoPuntoSegCam,
    DatosSegCam,
    HeadingSegCam,
    RefsSegCam,
    SpeedSegCam,
)
from bbcs.contracts.robot import RobotTelemetry

from .uav_stack import DEADLINE_S, INITIAL_ROUTES, SLOT, Stack, wait_until

PF = "path_follower"
# far waypoints (≈ 1 km north of home): queued, never reached while a test looks at the queue
POINTS = [DatoPuntoSegCam(latitud=37.4217 + i * 1e-4, longitud=-6.0025, altura=30.0) for i in range(3)]
PATH = DatosSegCam(n_points=len(POINTS), puntos=POINTS)
WAYPOINTS = [p.InvalidatePath(), *(p.AddWaypoint(lat=pt.latitud, lon=pt.longitud, alt=pt.altura) for pt in POINTS)]
"""A path replaces the DSP's queue: emptied (acknowledged) first, then every waypoint."""
REFS = RefsSegCam(
    ref_altura=30.0, error_longitudinal=2.0, error_lateral=-1.0, ref_heading=0.25, ref_rpm_motor=1500.0
)
SET_REFS = p.SetRefs(
    ref_altura=30.0, error_longitudinal=2.0, error_lateral=-1.0, ref_heading=0.25, ref_rpm_motor=1500.0
)
BAD_HEADING = {"heading": math.pi}
ZERO_POINT = {"latitud": 0.0, "longitud": 0.0, "altura": 0.0}
BAD_PATH = {"n_points": 2, "puntos": [ZERO_POINT]}  # a count that does not match the list
BAD_REFS = {
    "ref_altura": 0.0,
    "error_longitudinal": 0.0,
    "error_lateral": 0.0,
    "ref_heading": 0.0,
    "ref_rpm_motor": 1800.5,
}


def mode(m: int) -> ControlModoSegCam:
    return ControlModoSegCam(modo_o_comando=0, modo_de_funcionamiento=m)


ABORT = ControlModoSegCam(modo_o_comando=1, numero_de_comando=0)
# what the DSP receives for each mode row of SPEC §3.3 (mode 1, with the current heading: enter_mode_1)
ENTER = {
    0: [p.SetMode(mode=p.Mode(0)), p.SetTracking(enable=True)],
    2: [p.SetMode(mode=p.Mode(2)), p.SetTracking(enable=False), p.InvalidatePath()],
    4: [p.SetTracking(enable=False), p.InvalidatePath(), p.SetMode(mode=p.Mode(4))],
    5: [p.SetTracking(enable=False), p.InvalidatePath(), p.SetMode(mode=p.Mode(5))],
    6: [p.SetMode(mode=p.Mode(6))],
}


@pytest.fixture(scope="module")
def uav(tmp_path_factory) -> Iterator[Stack]:
    stack = Stack(tmp_path_factory.mktemp("uav_modes"), [PF, "telemetry"])
    try:
        yield stack.start()
    finally:
        stack.close()


@pytest.fixture
def stack(uav: Stack) -> Stack:
    """Every test starts semi-automatic (mode 2): tracking off, no path, speed 0 — set through the bus."""
    mark = uav.mark()
    uav.send("speed", SpeedSegCam(speed=0.0))
    uav.expect(
        mark, [p.SetSpeed(speed=0.0)], "reset speed"
    )  # two inputs: one at a time keeps the order known
    enter(uav, 2, "reset to mode 2")
    uav.wait_state("reset", mode=2, tracking=False, path_valid=False, queue=0)
    return uav


def enter(stack: Stack, m: int, what: str) -> None:
    mark = stack.mark()
    stack.send("modo", mode(m))
    stack.expect(mark, ENTER[m], what)


def load_path(stack: Stack) -> None:
    """Mode 0 and three queued waypoints: the state the mode rows that drop a path start from."""
    enter(stack, 0, "mode 0 before a path")
    mark = stack.mark()
    stack.send("path", PATH)
    stack.expect(mark, WAYPOINTS, "three waypoints in mode 0")
    stack.wait_state("path loaded", mode=0, tracking=True, path_valid=True, queue=3)


# --- SPEC §3.3's table, one test per row --------------------------------------------------------------


def test_abort_empties_the_queue(stack: Stack) -> None:
    load_path(stack)
    mark = stack.mark()
    stack.send("modo", ABORT)
    stack.expect(mark, [p.Abort()], "abort")
    stack.wait_state("after abort", mode=0, path_valid=False, queue=0)


def test_mode_0_sends_the_mode_and_enables_tracking(stack: Stack) -> None:
    enter(stack, 0, "mode 0")
    stack.wait_state("mode 0", mode=0, tracking=True, path_valid=False, queue=0)


def enter_mode_1(stack: Stack) -> None:
    """Mode 1: the current heading (from the DSP's own telemetry, in degrees), the mode, tracking on."""
    heading = stack.latest().heading
    assert heading is not None
    mark = stack.mark()
    stack.send("modo", mode(1))
    wait_until(lambda: len(stack.received(mark)) >= 3, DEADLINE_S, "mode 1")
    stack.barrier()
    got = stack.received(mark)
    assert [r["name"] for r in got] == ["SET_HEADING", "SET_MODE", "SET_TRACKING"], got
    assert got[1]["fields"]["mode"] == 1 and got[2]["fields"]["enable"] is True, got
    # the follower sends the heading of the last telemetry it saw: the simulated helicopter's heading is a
    # physical state that may still be settling between two telemetry frames (on a loaded machine, by more
    # than half a degree between the test's look and the follower's), so the heading sent lies between the
    # headings seen just before and just after it, within the half degree of one frame
    after = stack.latest().heading
    assert after is not None
    low, high = min(heading, after) - 0.5, max(heading, after) + 0.5
    assert low <= got[0]["fields"]["heading_deg"] <= high, (got, heading, after)


def test_mode_1_sends_the_current_heading_with_the_mode(stack: Stack) -> None:
    enter_mode_1(stack)
    stack.wait_state("mode 1", mode=1, tracking=True, path_valid=False, queue=0)


@pytest.mark.parametrize("m", [2, 4, 5])
def test_modes_2_4_5_disable_tracking_and_invalidate_the_path(stack: Stack, m: int) -> None:
    load_path(stack)
    enter(stack, m, f"mode {m}")
    stack.wait_state(f"mode {m}", mode=m, tracking=False, path_valid=False, queue=0)


def test_mode_3_flies_the_trajectory_onboard_through_bridge_references(stack: Stack) -> None:
    """Mode 3: SET_MODE 3 and INVALIDATE_PATH for the mode (the DSP's queue is not flown in it, and a path left
    there would be flown again by a later mode 0/1); DATOS stays onboard (no ADD_WAYPOINT); the follower answers the
    DSP telemetry with SET_REFS and the aircraft climbs and moves north along the trajectory; abort stops it."""
    mark = stack.mark()
    stack.send("modo", mode(3))
    stack.expect(mark, [p.SetMode(mode=p.Mode(3)), p.InvalidatePath()], "mode 3")
    stack.wait_state("mode 3", mode=3, queue=0)
    start = stack.latest().position
    assert start is not None
    mark = stack.mark()
    stack.send("speed", SpeedSegCam(speed=4.0))
    stack.barrier()
    stack.send("path", PATH)
    wait_until(lambda: any(r["name"] == "SET_REFS" for r in stack.received(mark)), DEADLINE_S, "REFS from mode 3")
    stack.wait_telemetry(
        lambda t: t.position is not None and t.position.lat > start.lat + 3e-5 and t.position.alt > start.alt + 1,
        "the aircraft flying up and north along the onboard trajectory",
        45.0,
    )
    assert "ADD_WAYPOINT" not in {r["name"] for r in stack.received(mark)}, "mode 3 queued waypoints on the DSP"
    stack.wait_state("DSP queue untouched", mode=3, queue=0)
    abort_mark = stack.mark()
    reports_before = len(stack.reports)
    stack.send("modo", ABORT)
    wait_until(lambda: any(r["name"] == "ABORT" for r in stack.received(abort_mark)), DEADLINE_S, "abort")
    stack.barrier()
    after = stack.mark()
    now = stack.latest().time_ms
    stack.wait_telemetry(lambda t: t.time_ms > now + 500, "half a second of telemetry after the abort")
    stack.barrier()
    assert [r["name"] for r in stack.received(after)] == [], "mode 3 kept sending after the abort"
    # the only reports: REFS batches still queued when ABORT jumped the queue (FLUSHED, expected); taken out so
    # later tests see only their own
    ours = stack.reports[reports_before:]
    assert all(r.sender == PF and r.name == "FLUSHED" for r in ours), ours
    del stack.reports[reports_before:]


def test_mode_6_sends_bridge_mode(stack: Stack) -> None:
    enter(stack, 6, "mode 6")
    stack.wait_state("mode 6", mode=6, tracking=False, path_valid=False, queue=0)


def test_telemetry_module_reports_the_dsp_state(stack: Stack) -> None:
    """The telemetry process turns the same DSP telemetry into RobotTelemetry for everyone."""
    import msgspec

    from bbcs import keys

    seen: list[RobotTelemetry] = []
    decode = msgspec.msgpack.Decoder(RobotTelemetry).decode
    sub = stack.session.declare_subscriber(
        keys.slot_key("r1", "telemetry", "telemetry"), lambda s: seen.append(decode(s.payload.to_bytes()))
    )
    try:
        load_path(stack)
        wait_until(
            lambda: (
                bool(seen)
                and seen[-1].mode == 0
                and seen[-1].waypoints_queued == 3
                and seen[-1].tracking
                and seen[-1].path_valid
            ),
            15,
            "RobotTelemetry of mode 0 with 3 waypoints",
        )
        assert seen[-1].mode_name == "PATH_AUTO_HEADING" and seen[-1].position is not None
    finally:
        sub.undeclare()


# --- what each input does in each mode ----------------------------------------------------------------


def ignored_in_mode(stack: Stack, m: int, source: str, value, bad: dict, code: int, slot: str) -> None:
    """In mode ``m``, ``value`` on ``source`` is handled (``bad`` after it gives ``code``) and reaches nothing."""
    enter(stack, m, f"mode {m}")
    mark = stack.mark()
    stack.send(source, value)
    stack.handled(PF, source, bad, code, f"{source} in mode {m}")
    stack.barrier()
    assert stack.received(mark) == [], f"{slot} reached the DSP in mode {m}"


def test_heading_reaches_the_dsp_in_degrees_in_mode_1_only(stack: Stack) -> None:
    for m in (0, 6, 2):  # 2 last: the mode the reset left, re-entered
        ignored_in_mode(stack, m, "heading", HeadingSegCam(heading=1.0), BAD_HEADING, E.HEADING_OUT_OF_RANGE, "HEADING")
    enter_mode_1(stack)
    for rad, deg in ((-math.pi / 2, -90.0), (0.5, math.degrees(0.5)), (-math.pi, -180.0)):
        mark = stack.mark()
        stack.send("heading", HeadingSegCam(heading=rad))
        stack.expect(mark, [p.SetHeading(heading_deg=deg)], f"heading {rad} rad in mode 1")


def test_path_reaches_the_dsp_in_modes_0_and_1_only(stack: Stack) -> None:
    for m in (6, 2):
        ignored_in_mode(stack, m, "path", PATH, BAD_PATH, E.N_POINTS_MISMATCH, "DATOS")
        stack.wait_state(f"no path in mode {m}", path_valid=False, queue=0)
    enter_mode_1(stack)
    stack.wait_state("mode 1", mode=1, tracking=True)
    mark = stack.mark()
    stack.send("path", PATH)
    stack.expect(mark, WAYPOINTS, "path in mode 1")
    stack.wait_state("path in mode 1", mode=1, path_valid=True, queue=3)
    enter(stack, 0, "mode 0 after mode 1")  # keeps the queued path until a new one replaces it
    stack.wait_state("mode 0 keeps the path", mode=0, tracking=True, path_valid=True, queue=3)
    mark = stack.mark()
    stack.send("path", PATH)
    stack.expect(mark, WAYPOINTS, "path in mode 0")
    stack.wait_state("a new path replaces the queue", mode=0, tracking=True, path_valid=True, queue=3)


def test_refs_reach_the_dsp_in_mode_6_only(stack: Stack) -> None:
    for m in (0, 2):
        ignored_in_mode(stack, m, "refs", REFS, BAD_REFS, E.REF_RPM_OUT_OF_RANGE, "REFS")
    enter(stack, 6, "mode 6")
    mark = stack.mark()
    stack.send("refs", REFS)
    stack.expect(mark, [SET_REFS], "refs as they are in mode 6")
    # the DSP's answer as it gave it (the record, already in after the barrier); its report, if it refused,
    # goes on the bus with no order against that record
    assert [r["status"] for r in stack.received(mark)] == [0], "the DSP refused the bridge references"
    assert not [r for r in stack.reports if r.sender == PF], "the DSP refused the bridge references"


def test_speed_reaches_the_dsp_in_every_mode(stack: Stack) -> None:
    for m, speed in ((2, 3.0), (0, 8.0), (6, 0.5)):
        if m != 2:
            enter(stack, m, f"mode {m}")
        mark = stack.mark()
        stack.send("speed", SpeedSegCam(speed=speed))
        stack.expect(mark, [p.SetSpeed(speed=speed)], f"speed {speed} in mode {m}")
        wait_until(
            lambda s=speed: stack.latest().speed is not None and stack.latest().speed.commanded == s,
            15,
            f"DSP commanded speed {speed}",
        )


# --- out-of-range data: the documented code, nothing to the DSP ---------------------------------------

BAD = [  # (input, raw datum, code, mode in which a good datum of that input would reach the DSP)
    ("modo", {"modo_o_comando": 0, "modo_de_funcionamiento": 7}, E.MODE_OUT_OF_RANGE, 0),
    ("modo", {"modo_o_comando": 1, "numero_de_comando": 1}, E.COMMAND_OUT_OF_RANGE, 0),
    ("heading", {"heading": math.pi}, E.HEADING_OUT_OF_RANGE, 1),
    ("speed", {"speed": -0.5}, E.SPEED_OUT_OF_RANGE, 0),
    ("speed", {"speed": 8.5}, E.SPEED_ABOVE_MAX, 0),
    ("path", {"n_points": 0, "puntos": []}, E.N_POINTS_OUT_OF_RANGE, 0),
    (
        "path",
        {"n_points": 2, "puntos": [ZERO_POINT, {**ZERO_POINT, "latitud": 90.5}]},
        E.LATITUD_OUT_OF_RANGE,
        0,
    ),
    ("refs", {**BAD_REFS, "ref_rpm_motor": 1500.0, "ref_heading": -3.2}, E.REF_HEADING_OUT_OF_RANGE, 6),
    ("refs", BAD_REFS, E.REF_RPM_OUT_OF_RANGE, 6),
    ("pf_control", {"slot_entrada_heading": -2}, E.CONTROL_ENTRADA_OUT_OF_RANGE, 0),
]


@pytest.mark.parametrize(("source", "raw", "code", "m"), BAD, ids=[f"{b[0]}-{int(b[2])}" for b in BAD])
def test_out_of_range_datum_gives_its_code_and_nothing_reaches_the_dsp(
    stack: Stack, source, raw, code, m
) -> None:
    if m == 1:
        enter_mode_1(stack)
    else:
        enter(stack, m, f"mode {m}")
    stack.refused(PF, source, raw, code)


def test_bad_control_entrada_keeps_the_routes(stack: Stack) -> None:
    errors = stack.error_mark(PF)
    stack.send_raw("pf_control", {"slot_entrada_control_modos": SLOT["modo"], "slot_entrada_datos": -5})
    stack.expect_error(PF, errors, E.CONTROL_ENTRADA_OUT_OF_RANGE, "bad CONTROL_ENTRADA")
    load_path(stack)  # CONTROL_MODO and DATOS still read from their slots
    stack.route(
        PF,
        ControlEntradaSegCam(
            **{
                f"slot_entrada_{k}": v
                for k, v in (
                    ("control_modos", SLOT["modo"]),
                    ("heading", SLOT["heading"]),
                    ("speed", SLOT["speed"]),
                    ("datos", SLOT["path"]),
                )
            }
        ),
        INITIAL_ROUTES[PF],
    )
