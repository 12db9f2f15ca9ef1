"""The survey mission path on the real UAV manifest (bbcs_conf/uav1_lidar_sim.toml) with every simulator: the
manager's ``survey`` task routes the path follower's DATOS to the generator's slot, a survey request is
planned, and its waypoints reach the DSP simulator (its record of received commands); ending the task
routes DATOS back to the RAL's slot."""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts import mri
from bbcs.contracts.path_follower import DatosSegCam
from bbcs.contracts.trajectory import SurveyRequest, TrajectoryRequest, TrajectoryStatus, Vertex
from bbcs.testing import wait_until
from modules.dsp.sim.record import read_record

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "tests" / "module_manager"))
from launch_support import Launch  # noqa: E402

MRI_S = 20.0
HOME = (37.4117, -6.0025)
POLYGON = [Vertex(lat=HOME[0] + dlat, lon=HOME[1] + dlon)
           for dlat, dlon in ((-0.0015, -0.003), (-0.0015, 0.003), (0.0015, 0.003), (0.0015, -0.003))]


def manifest(tmp_path: Path) -> Path:
    text = (ROOT / "bbcs_conf" / "uav1_lidar_sim.toml").read_text()
    text = text.replace('conf = "uav1.conf"', f'conf = "{ROOT / "bbcs_conf" / "uav1.conf"}"')
    record = tmp_path / "dsp.jsonl"
    dsp = '"--tcp", "127.0.0.1:{port:dsp}"'
    text = text.replace(dsp + "]", f'{dsp}, "--record", "{record}"]')
    text = text.replace('params = { ldmrs_host', f'params = {{ out_dir = "{tmp_path}", ldmrs_host')
    path = tmp_path / "uav1_lidar_sim.toml"
    path.write_text(text)
    return path


def dsp_records(tmp_path: Path) -> list[dict]:
    return read_record(tmp_path / "dsp.jsonl")


@pytest.mark.timeout(240)
def test_survey_task_routes_the_generator_to_the_path_follower_and_the_dsp_gets_the_lines(tmp_path, clients):
    launch = Launch(manifest(tmp_path), tmp_path)
    try:
        launch.wait_line("modules up", timeout_s=150)
        s = clients(launch.port)
        statuses: list[TrajectoryStatus] = []
        decode = msgspec.msgpack.Decoder(TrajectoryStatus).decode
        got = threading.Event()

        def on_status(sample) -> None:
            statuses.append(decode(sample.payload.to_bytes()))
            got.set()

        paths: list[DatosSegCam] = []
        decode_path = msgspec.msgpack.Decoder(DatosSegCam).decode
        subs = [s.declare_subscriber(keys.slot_key("uav1", "trajectory", "status"), on_status),
                s.declare_subscriber(keys.slot_key("uav1", "trajectory", "survey"),
                                     lambda smp: paths.append(decode_path(smp.payload.to_bytes())))]
        reply = mri.call(s, "uav1", "task", mri.SetTask(name="survey"), MRI_S)
        assert reply.ok, reply.reason
        assert mri.call(s, "uav1", "routes", mri.ListRoutes(), MRI_S).data.routes["path_follower"]["datos"] == 30
        req = TrajectoryRequest(request_id=1, survey=SurveyRequest(polygon=POLYGON, height=60.0, overlap=0.2))
        s.put(keys.slot_key("uav1", "trajectory", "request"), msgspec.msgpack.encode(req))
        assert got.wait(30), "no answer from the generator"
        assert statuses[0].accepted, statuses[0].reason
        wait_until(lambda: len(paths) == 1, 30, "the planned path")
        path = paths[0].puntos
        assert statuses[0].n_points == len(path) > 10

        def waypoints() -> list[dict]:
            return [r["fields"] for r in dsp_records(tmp_path) if r["name"] == "ADD_WAYPOINT"]

        wait_until(lambda: len(waypoints()) >= 10, 60, "waypoints at the DSP simulator")
        sent = waypoints()
        # the DSP protocol carries 1e-4 degrees; the follower feeds the path in order from its start
        for wp, p in zip(sent, path, strict=False):
            assert abs(wp["lat"] - p.latitud) <= 0.51e-4 and abs(wp["lon"] - p.longitud) <= 0.51e-4
            assert wp["alt"] == pytest.approx(12.0 + 60.0)
        reply = mri.call(s, "uav1", "task", mri.EndTask(task_type="movement"), MRI_S)
        assert reply.ok, reply.reason
        assert mri.call(s, "uav1", "routes", mri.ListRoutes(), MRI_S).data.routes["path_follower"]["datos"] == 11
        for sub in subs:
            sub.undeclare()
    finally:
        code = launch.stop()
        launch.cleanup()
    assert code == 0
