"""Issue 33 on the second robot kind: the shipped simulated uQuad (``bbcs_conf/uquad1_sim.toml``) and a simulated
UAV whose router meshes with it, both served by one gateway: two MAVLink system ids in one session (pymavlink), the
uQuad taken off and landed by MAVSDK. Checked by effect on the GRI (a ground station of its own) and on what the
MAVLink clients were told.
"""

from __future__ import annotations

import asyncio
import math
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from bbcs.contracts import gri
from bbcs.testing import wait_until
from ral.gcs.api import Gcs, session_config

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1] / "system"))
sys.path.insert(0, str(HERE.parents[1] / "module_manager"))
from launch_support import Launch  # noqa: E402
from mavlink_support import ROOT, Mav, first, gateway, run_async  # noqa: E402
from test_gcs_mission import sim_manifest  # noqa: E402

pytestmark = pytest.mark.timeout(300)
QUAD, UAV = "uquad1", "uav1"
QUAD_MANIFEST = ROOT / "bbcs_conf" / "uquad1_sim.toml"


def uquad_manifest(tmp_path: Path) -> Path:
    """The shipped uquad1_sim.toml as it is, free-running (a fleet is not in lockstep, docs/simulation.md), with
    the loggers writing into tmp_path (the link-loss failsafe as shipped: nothing here loses its link)."""
    text = QUAD_MANIFEST.read_text().replace('conf = "uquad1.conf"', f'conf = "{QUAD_MANIFEST.parent / "uquad1.conf"}"')
    for kind in ("imu_raw", "control", "state"):
        old = f'params = {{ kind = "{kind}" }}'
        assert old in text, f"uquad1_sim.toml's {kind} logger changed"
        text = text.replace(old, f'params = {{ kind = "{kind}", dir = "{tmp_path}" }}')
    path = tmp_path / "uquad1_sim.toml"
    path.write_text(text)
    return path


class Fleet:
    def __init__(self, gcs: Gcs, udp: int, tcp: int) -> None:
        self.gcs, self.udp, self.tcp = gcs, udp, tcp
        self.states: dict[str, gri.GriState] = {}
        self.events: list[gri.GriEvent] = []
        gcs.watch("*", lambda s: self.states.__setitem__(s.robot, s))
        gcs.events(QUAD, self.events.append)

    def task_end(self, mark: int, what: str) -> None:
        """The uQuad's first task to end after ``mark`` completed (else: what the GRI said instead)."""
        ended = ("task_completed", "task_failed", "task_cancelled", "task_replaced", "aborted")
        wait_until(lambda: any(e.kind in ended for e in self.events[mark:]), 90, f"the {what} ended")
        end = next(e for e in self.events[mark:] if e.kind in ended)
        assert end.kind == "task_completed", (what, end, self.events[mark:])

    def state(self, robot: str, pred, what: str, timeout_s: float = 30.0) -> gri.GriState:  # noqa: ANN001
        wait_until(lambda: robot in self.states and pred(self.states[robot]), timeout_s, what)
        return self.states[robot]


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Fleet]:
    quad_dir, uav_dir = tmp_path_factory.mktemp("uquad"), tmp_path_factory.mktemp("uav")
    manifest, _record = sim_manifest(uav_dir)
    uav = Launch(manifest, uav_dir)
    quad = gcs = gw = None
    try:
        uav.wait_line("modules up in", 120)
        # the uQuad's router meshes with the UAV's (a fleet of two): one router reaches both robots. The UAV starts
        # first: the uQuad's processes run at a flight computer's priority (nice -10) and would starve its start
        quad_manifest = uquad_manifest(quad_dir)
        text = quad_manifest.read_text()
        listen = 'listen = ["tcp/127.0.0.1:7448"]'
        assert listen in text
        quad_manifest.write_text(text.replace(listen, f'{listen}\npeers = ["tcp/127.0.0.1:{uav.port}"]'))
        quad = Launch(quad_manifest, quad_dir)
        quad.wait_line("modules up in", 120)
        gcs = Gcs(session_config([f"tcp/127.0.0.1:{quad.port}"]), name="observer", timeout_s=10.0)
        gw, udp, tcp = gateway(quad.port, "--manifest", str(ROOT / "bbcs_conf" / "uav1_sim.toml"), "--robot",
                               "uav1=1", "--manifest", str(ROOT / "bbcs_conf" / "uquad1_sim.toml"), "--robot",
                               "uquad1=2", "-v")
        gw.wait_line(f"robot {QUAD} is MAVLink system 2", 60)
        gw.wait_line(f"robot {UAV} is MAVLink system 1", 60)
        yield Fleet(gcs, udp, tcp)
    finally:
        if gw is not None:
            gw.close()
            print("gateway output (the last 60 lines):", *gw.lines[-60:], sep="\n")
        if gcs is not None:
            gcs.close()
        for la in (quad, uav):
            if la is not None:
                la.stop()
                la.cleanup()


def _metres(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    return math.hypot((lat2 - lat1) * 111_320.0, (lon2 - lon1) * 111_320.0 * math.cos(math.radians(lat1)))


def test_two_robots_are_two_system_ids_in_one_session(fleet: Fleet) -> None:
    mav = Mav(fleet.tcp)
    try:
        types = {}
        for sysid, robot in ((1, UAV), (2, QUAD)):
            beat = mav.wait(0, "HEARTBEAT", sysid=sysid, timeout_s=20)
            types[robot] = beat.type
            s = fleet.state(robot, lambda s: s.position is not None, f"{robot}'s position")
            mark = mav.mark()
            pos = mav.wait(mark, "GLOBAL_POSITION_INT", sysid=sysid, timeout_s=10)
            now = fleet.states[robot].position
            assert now is not None and s.position is not None
            assert _metres(pos.lat / 1e7, pos.lon / 1e7, now.lat, now.lon) < 1.0, robot
            assert abs(pos.alt / 1000 - now.alt) < 1.0, robot
        assert types == {UAV: 4, QUAD: 2}  # MAV_TYPE_HELICOPTER, MAV_TYPE_QUADROTOR
        # each answers its own parameters: the uQuad's .conf, not the UAV's
        mark = mav.mark()
        mav.mav.param_request_read_send(2, 1, b"MAX_SPEED", -1)
        mav.mav.param_request_read_send(1, 1, b"MAX_SPEED", -1)
        wait_until(lambda: len(mav.since(mark, "PARAM_VALUE")) >= 2, 10, "both MAX_SPEED values")
        assert {m.get_srcSystem(): m.param_value for m in mav.since(mark, "PARAM_VALUE")} == {1: 8.0, 2: 4.0}
    finally:
        mav.close()


def test_uquad_takes_off_and_lands_from_mavsdk(fleet: Fleet) -> None:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    start = fleet.state(QUAD, lambda s: s.position is not None and s.home is not None and s.airborne is False,
                        "the uQuad on the ground, its position known", 60)
    assert start.home is not None

    async def session():  # noqa: ANN202
        m = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        try:
            await m.add_any_connection(f"udpin://127.0.0.1:{fleet.udp}")

            async def quad():  # noqa: ANN202
                while True:
                    for system in await m.get_systems():
                        if await system.get_system_id() == 2 and await system.has_autopilot():
                            return system
                    await asyncio.sleep(0.2)

            system = await asyncio.wait_for(quad(), 30)
            tel, act = TelemetryAsync(system), ActionAsync(system)
            pos = await first(tel.subscribe_position())
            here = fleet.states[QUAD].position
            assert here is not None and _metres(pos.latitude_deg, pos.longitude_deg, here.lat, here.lon) < 1.0
            mark = len(fleet.events)
            await act.takeoff()  # the uQuad's own take-off height: TAKEOFF_HEIGHT_DEFAULT, 3 m
            await asyncio.to_thread(fleet.task_end, mark, "take_off")
            await first(tel.subscribe_position(), lambda p: p.relative_altitude_m > 2.4, 20)
            mark = len(fleet.events)
            await act.land()
            await asyncio.to_thread(fleet.task_end, mark, "land")
            await first(tel.subscribe_in_air(), lambda x: not x, 20)
        finally:
            m.destroy()

    mark = len(fleet.events)
    run_async(session, 200)
    done = [e for e in fleet.events[mark:] if e.kind == "task_completed"]
    assert len(done) == 2, fleet.events[mark:]  # the take-off, then the landing
    landed = fleet.state(QUAD, lambda s: s.airborne is False, "landed in the GRI")
    assert landed.position is not None
    # nothing unrequested follows: no task starts or fails in the next seconds
    after = len(fleet.events)
    time.sleep(5.0)
    assert [e.kind for e in fleet.events[after:] if e.kind.startswith("task_")] == []
