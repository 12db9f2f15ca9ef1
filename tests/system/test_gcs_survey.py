"""Issue 18: the ground station asks for a survey as a task, on the launched survey UAV
(``bbcs_conf/uav1_lidar_sim.toml``: manager, RAL, path follower, trajectory generator, lidar logger and every
simulator). The RAL admits the survey, starts the manifest's ``survey`` task (DATOS from the generator's slot),
sends the generator the request; the generated waypoints reach the DSP simulator (its record), the aircraft flies
them (GRI position) and the GRI reports the task completed; afterwards DATOS is routed back. A survey the
generator cannot fly is refused with the generator's reason and the task ends failed. The robot flies in
lockstep at ``--speed max`` (docs/simulation.md).
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts import tasks as t
from bbcs.contracts.path_follower import DatosSegCam
from bbcs.testing import wait_until

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_gcs_mission import ROBOT, SimRobot, connect  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "module_manager"))
from launch_support import ROOT, Launch  # noqa: E402

HOME = (37.4117, -6.0025)
M_PER_DEG = 111_320.0
# about 60 m × 90 m north of home: two sweep lines at 25 m
POLYGON = [t.Vertex(lat=HOME[0] + dlat, lon=HOME[1] + dlon)
           for dlat, dlon in ((0.0003, -0.0003), (0.0003, 0.0004), (0.0011, 0.0004), (0.0011, -0.0003))]


def manifest(tmp_path: Path) -> tuple[Path, Path]:
    text = (ROOT / "bbcs_conf" / "uav1_lidar_sim.toml").read_text()
    text = text.replace('conf = "uav1.conf"', f'conf = "{ROOT / "bbcs_conf" / "uav1.conf"}"')
    record = tmp_path / "dsp.jsonl"
    dsp = '"--tcp", "127.0.0.1:{port:dsp}"'
    assert dsp + "]" in text, "the DSP simulator's command line in uav1_lidar_sim.toml changed"
    text = text.replace(dsp + "]", f'{dsp}, "--record", "{record}"]')
    text = text.replace('params = { ldmrs_host', f'params = {{ out_dir = "{tmp_path}", ldmrs_host')
    if "lockstep = true" not in text:  # nothing here looks at the scans (test_survey_dtm does, free-running)
        text = text.replace("\n[bus]\n", "\n[sim]\nlockstep = true\n\n[bus]\n", 1)
    path = tmp_path / "uav1_lidar_sim.toml"
    path.write_text(text)
    return path, record


@pytest.fixture
def robot(tmp_path: Path) -> Iterator[SimRobot]:
    path, record = manifest(tmp_path)
    la = Launch(path, tmp_path, "--speed", "max")
    gcs = None
    try:
        la.wait_line("modules up", timeout_s=150)
        gcs = connect(la.port, "surveyor")
        robot = SimRobot(la, gcs, record)
        robot.wait_state(lambda s: s.manager_up and s.position is not None and "survey" in s.available, 60,
                         "GRI state with position and the survey task")
        yield robot
    finally:
        if gcs is not None:
            gcs.close()
        la.stop()
        la.cleanup()


@pytest.mark.timeout(300)
def test_gcs_survey_and_orbit_are_planned_flown_and_completed(robot: SimRobot) -> None:
    paths: list[DatosSegCam] = []
    sub = robot.gcs.session.declare_subscriber(
        keys.slot_key(ROBOT, "trajectory", "survey"),
        lambda s: paths.append(msgspec.msgpack.decode(s.payload.to_bytes(), type=DatosSegCam)),
    )
    orbits: list[DatosSegCam] = []
    orbit_sub = robot.gcs.session.declare_subscriber(
        keys.slot_key(ROBOT, "trajectory", "orbit"),
        lambda s: orbits.append(msgspec.msgpack.decode(s.payload.to_bytes(), type=DatosSegCam)),
    )
    try:
        robot.ensure_airborne()
        # a survey the generator cannot fly (lines closer than twice the turn radius): refused with its reason
        # before anything starts (the generator is asked first), so no task is started, replaced or failed
        refused_at = len(robot.events)
        low = robot.gcs.send(ROBOT, t.Survey(polygon=POLYGON, height=8.0, overlap=0.5))
        assert not low.accepted and "trajectory generator refused the survey" in low.reason, low
        assert low.task_id == 0 and not paths
        robot.wait_event(lambda e: e.kind == "task_rejected" and "refused the survey" in e.detail, 10,
                         "the refusal at the ground station", after=refused_at)

        mark = len(robot.commands())
        start = len(robot.events)
        reply = robot.gcs.send(ROBOT, t.Survey(polygon=POLYGON, height=25.0, overlap=0.1))
        assert reply.accepted, reply.reason
        wait_until(lambda: len(paths) >= 1, 20, "the generated survey path")
        planned = paths[-1].puntos
        assert len(planned) >= 4
        done = robot.wait_event(lambda e: e.task_id == reply.task_id and e.kind != "task_accepted", 120,
                                "the survey ended", after=start)
        assert done.kind == "task_completed", done
        assert not [e for e in robot.events[refused_at:] if e.kind == "task_failed"], "the refusal failed a task"
        sent = robot.commands()[mark:]
        names = [c["name"] for c in sent]
        added = [(round(c["fields"]["lat"], 4), round(c["fields"]["lon"], 4)) for c in sent
                 if c["name"] == "ADD_WAYPOINT"]
        assert added == [(round(p.latitud, 4), round(p.longitud, 4)) for p in planned], (
            "the DSP received exactly the generated waypoints"
        )
        speeds = [c["fields"]["speed"] for c in sent[: names.index("ADD_WAYPOINT")] if c["name"] == "SET_SPEED"]
        assert speeds and speeds[-1] == pytest.approx(5.0), "the survey flies at the cruise speed, set first"
        last = planned[-1]
        pos = robot.state.position
        assert pos is not None
        assert abs(pos.lat - last.latitud) * M_PER_DEG < 10 and abs(pos.alt - last.altura) < 3, (
            f"the aircraft is at the survey's end: {pos} vs {last}"
        )
        routes = robot.gcs.routes(ROBOT)
        assert routes.routes["path_follower"]["datos"] != 30, "DATOS routed back after the survey"

        # an orbit around home, asked the same way
        mark = len(robot.commands())
        start = len(robot.events)
        orbit = robot.gcs.send(ROBOT, t.Orbit(lat=HOME[0], lon=HOME[1], radius=30.0, height=20.0))
        assert orbit.accepted, orbit.reason
        wait_until(lambda: len(orbits) >= 1, 20, "the generated orbit")
        circle = orbits[-1].puntos
        done = robot.wait_event(lambda e: e.task_id == orbit.task_id and e.kind != "task_accepted", 120,
                                "the orbit ended", after=start)
        assert done.kind == "task_completed", done
        added = [(round(c["fields"]["lat"], 4), round(c["fields"]["lon"], 4)) for c in robot.commands()[mark:]
                 if c["name"] == "ADD_WAYPOINT"]
        assert added == [(round(p.latitud, 4), round(p.longitud, 4)) for p in circle]
        assert robot.gcs.routes(ROBOT).routes["path_follower"]["datos"] != 31, "DATOS routed back after the orbit"
    finally:
        sub.undeclare()
        orbit_sub.undeclare()
