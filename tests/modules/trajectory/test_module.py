"""The trajectory generator as a process on a real router: a survey request in, the path on the survey
slot and an accepted status out; a bad request refused with its reason and no path."""

from __future__ import annotations

import math
import threading

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts.path_follower import DatosSegCam
from bbcs.contracts.trajectory import OrbitRequest, SurveyRequest, TrajectoryRequest, TrajectoryStatus, Vertex
from bbcs.geodesy import LocalFrame
from bbcs.testing import stop_process, wait_until
from modules.trajectory.planning import line_spacing

POLYGON = [Vertex(lat=37.4260, lon=-6.0040), Vertex(lat=37.4260, lon=-5.9960),
           Vertex(lat=37.4290, lon=-5.9960), Vertex(lat=37.4290, lon=-6.0040)]


@pytest.fixture
def generator(processes, router, sessions):
    s = sessions()
    got: dict[str, list] = {"survey": [], "orbit": [], "status": []}
    alive = threading.Event()
    subs = [s.liveliness().declare_subscriber(keys.alive_key("r1", "trajectory"), lambda _: alive.set(),
                                              history=True)]
    for slot, typ in (("survey", DatosSegCam), ("orbit", DatosSegCam), ("status", TrajectoryStatus)):
        decode = msgspec.msgpack.Decoder(typ).decode
        subs.append(s.declare_subscriber(keys.slot_key("r1", "trajectory", slot),
                                         lambda smp, slot=slot, decode=decode: got[slot].append(
                                             decode(smp.payload.to_bytes()))))
    proc = processes.start(["-m", "modules.trajectory", "--robot", "r1", "--connect", f"tcp/127.0.0.1:{router}",
                            "--param", "ground_altitude=12", "--param", "speed=10"])
    assert alive.wait(30), "the generator did not come up"

    def send(req: TrajectoryRequest) -> None:
        s.put(keys.slot_key("r1", "trajectory", "request"), msgspec.msgpack.encode(req))

    try:
        yield send, got
    finally:
        assert stop_process(proc, grace_s=10) == 0
        for sub in subs:
            sub.undeclare()


def test_a_survey_request_gives_a_lawnmower_on_the_survey_slot(generator) -> None:
    send, got = generator
    send(TrajectoryRequest(request_id=7, survey=SurveyRequest(polygon=POLYGON, height=80.0, overlap=0.2)))
    wait_until(lambda: got["status"] and got["survey"], 20, "the status and the path")
    status, path = got["status"][0], got["survey"][0]
    assert status.request_id == 7 and status.accepted and status.kind == "survey"
    assert status.line_spacing_m == pytest.approx(line_spacing(80.0, 0.2))
    assert path.n_points == len(path.puntos) == status.n_points > 10
    assert {p.altura for p in path.puntos} == {92.0}  # ground_altitude + height
    frame = LocalFrame(37.4275, -6.0)
    en = frame.to_enu([p.latitud for p in path.puntos], [p.longitud for p in path.puntos], 0.0)[:, :2]
    # the lines stay within the polygon's span plus the 10 m extension and the turns outside it
    assert en[:, 0].min() > -360 - 10 - 60 and en[:, 0].max() < 360 + 10 + 60
    assert not got["orbit"]


def test_a_refused_request_says_why_and_publishes_no_path(generator) -> None:
    send, got = generator
    send(TrajectoryRequest(request_id=8, orbit=OrbitRequest(centre=Vertex(lat=37.4, lon=-6.0), radius=5.0,
                                                            height=50.0)))
    send(TrajectoryRequest(request_id=9))
    wait_until(lambda: len(got["status"]) == 2, 20, "two answers")
    by_id = {s.request_id: s for s in got["status"]}
    assert not by_id[8].accepted and "turn radius" in by_id[8].reason
    assert not by_id[9].accepted and "exactly one" in by_id[9].reason
    send(TrajectoryRequest(request_id=10, orbit=OrbitRequest(centre=Vertex(lat=37.4, lon=-6.0), radius=100.0,
                                                             height=50.0)))
    wait_until(lambda: got["orbit"], 20, "the orbit")
    assert len(got["orbit"]) == 1 and not got["survey"]
    frame = LocalFrame(37.4, -6.0)
    en = frame.to_enu([p.latitud for p in got["orbit"][0].puntos], [p.longitud for p in got["orbit"][0].puntos],
                     0.0)[:, :2]
    assert all(math.isclose(r, 100.0, rel_tol=1e-6) for r in (en**2).sum(axis=1) ** 0.5)


def test_a_check_only_request_is_answered_and_publishes_no_path(generator) -> None:
    """The RAL's question before it starts a survey or an orbit: the answer, and no path a follower could fly."""
    send, got = generator
    orbit = OrbitRequest(centre=Vertex(lat=37.4, lon=-6.0), radius=100.0, height=50.0)
    send(TrajectoryRequest(request_id=11, orbit=orbit, check_only=True))
    send(TrajectoryRequest(request_id=12, check_only=True, orbit=OrbitRequest(
        centre=Vertex(lat=37.4, lon=-6.0), radius=5.0, height=50.0)))
    send(TrajectoryRequest(request_id=13, orbit=orbit))
    wait_until(lambda: len(got["status"]) == 3 and got["orbit"], 20, "three answers and the last one's path")
    by_id = {s.request_id: s for s in got["status"]}
    assert by_id[11].accepted and by_id[11].n_points == by_id[13].n_points > 0
    assert not by_id[12].accepted and "turn radius" in by_id[12].reason
    assert len(got["orbit"]) == 1  # only the request that was not a check published its path
