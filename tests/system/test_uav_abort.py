"""Abort while a 500-waypoint path is flown (SPEC §3.3, first row): both waypoint queues — the PC's (the
DSP process's unsent commands) and the DSP's — end up empty; the aircraft stops following and holds."""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest

from bbcs.contracts import dsp as p
from bbcs.contracts.dsp import LinkErrorCode
from bbcs.contracts.path_follower import ControlModoSegCam, DatoPuntoSegCam, DatosSegCam, SpeedSegCam

from .uav_stack import Stack, wait_until

PF = "path_follower"
HOME = (37.4117, -6.0025)
N = 500
# a straight line north of home, one waypoint per 1e-4° (≈ 11 m, the wire's resolution), 10 m above ground
PATH = DatosSegCam(
    n_points=N,
    puntos=[
        DatoPuntoSegCam(latitud=round(HOME[0] + (i + 1) * 1e-4, 4), longitud=HOME[1], altura=22.0)
        for i in range(N)
    ],
)
M_PER_DEG_LAT = 111_319.5


@pytest.fixture(scope="module")
def uav(tmp_path_factory) -> Iterator[Stack]:
    stack = Stack(tmp_path_factory.mktemp("uav_abort"), [PF], time_scale=10.0)
    try:
        yield stack.start()
    finally:
        stack.close()


def north_m(stack: Stack) -> float:
    pos = stack.latest().position
    assert pos is not None
    return (pos.lat - HOME[0]) * M_PER_DEG_LAT


def ground_speed(stack: Stack) -> float:
    v = stack.latest().velocity
    assert v is not None
    return math.hypot(v.vn, v.ve)


def fly_path(uav: Stack) -> int:
    """Cruise speed, mode 0, then the 500-waypoint path; returns the record mark before the path."""
    mark = uav.mark()
    uav.send("speed", SpeedSegCam(speed=8.0))
    uav.expect(mark, [p.SetSpeed(speed=8.0)], "cruise speed")
    mark = uav.mark()
    uav.send("modo", ControlModoSegCam(modo_o_comando=0, modo_de_funcionamiento=0))
    uav.expect(mark, [p.SetMode(mode=p.Mode(0)), p.SetTracking(enable=True)], "mode 0")
    mark = uav.mark()
    uav.send("path", PATH)
    wait_until(lambda: len(uav.received(mark)) >= 20, 15, "the first waypoints at the DSP")
    uav.wait_state("following", mode=0, tracking=True, path_valid=True)
    return mark


def abort_and_check(uav: Stack, mark: int) -> tuple[int, float]:
    """Abort; both queues must end up empty and the aircraft hold. Returns (waypoints sent, where it held)."""
    errors = uav.error_mark(PF)
    abort_mark = uav.mark()
    uav.send("modo", ControlModoSegCam(modo_o_comando=1, numero_de_comando=0))
    wait_until(
        lambda: any(r["name"] == "ABORT" for r in uav.received(abort_mark)), 15, "the ABORT at the DSP"
    )
    uav.barrier()
    # the PC's queue: nothing of the path goes out after the ABORT, and what had not gone out never will
    sent = uav.received(mark)
    names = [r["name"] for r in sent]
    waypoints = names.count("ADD_WAYPOINT")
    # a path replaces the DSP's queue: INVALIDATE_PATH, acknowledged, before its first waypoint
    assert names == ["INVALIDATE_PATH"] + ["ADD_WAYPOINT"] * waypoints + ["ABORT"], names[-5:]
    assert all(
        r["fields"]["lat"] == pytest.approx(pt.latitud, abs=1e-6)
        for r, pt in zip(sent[1 : 1 + waypoints], PATH.puntos[:waypoints], strict=True)
    )
    if waypoints < N:  # the ABORT overtook the rest of the path: dropped, and said so to the path follower
        wait_until(
            lambda: any(r.code == LinkErrorCode.FLUSHED and r.sender == PF for r in uav.reports),
            15,
            "the unsent waypoints reported flushed",
        )
        wait_until(lambda: 1000 + LinkErrorCode.FLUSHED in uav.errors[PF][errors:], 15, "flush forwarded")
    # the DSP's queue empty, the path invalid: it stops following and holds where it can stop
    uav.wait_state("after the abort", mode=0, path_valid=False, queue=0)
    uav.wait_telemetry(lambda t: math.hypot(t.velocity.vn, t.velocity.ve) < 0.3, "stopped", 30)
    held, t0 = north_m(uav), uav.latest().time_ms
    wait_until(lambda: uav.latest().time_ms > t0 + 3000, 15, "three more seconds of DSP time")
    assert abs(north_m(uav) - held) < 1.0 and ground_speed(uav) < 0.3, (
        "the aircraft kept moving after the abort"
    )
    assert uav.status().queue_length == 0
    uav.barrier()
    assert uav.received(mark)[waypoints + 2 :] == [], "the PC sent more after the abort"
    return waypoints, held


def test_abort_while_flying_a_500_waypoint_path(uav: Stack) -> None:
    mark = fly_path(uav)
    uav.wait_telemetry(
        lambda t: t.velocity is not None and t.velocity.vn > 2.0 and t.status.queue_length > 0,
        "the aircraft flying north along the path",
        30,
    )
    start = north_m(uav)
    wait_until(lambda: north_m(uav) > start + 5.0, 30, "position advancing along the path")
    waypoints, held = abort_and_check(uav, mark)
    assert held > start + 5.0
    print(f"\n{waypoints} of {N} waypoints at the DSP when the ABORT came; held {held - start:.1f} m on")


def test_abort_while_the_path_is_still_being_sent(uav: Stack) -> None:
    """The ABORT right behind the path jumps the DSP process's queue: what is unsent of the path stays so."""
    mark = uav.mark()
    uav.send("modo", ControlModoSegCam(modo_o_comando=0, modo_de_funcionamiento=2))
    uav.expect(mark, [p.SetMode(mode=p.Mode(2)), p.SetTracking(enable=False), p.InvalidatePath()], "reset")
    mark = fly_path(uav)
    waypoints, _ = abort_and_check(uav, mark)
    print(f"\n{waypoints} of {N} waypoints at the DSP when the ABORT came")
