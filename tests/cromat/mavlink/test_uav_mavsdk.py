"""Issue 33 end to end on the shipped simulated UAV (``bbcs_conf/uav1_sim.toml`` in lockstep at ``--speed max``): the
gateway (``cromat mavlink``, a process) on the robot's router, flown by MAVSDK as any MAVLink vehicle is, read by
pymavlink. Checked by effect: what reached the DSP simulator (its record), what the GRI shows (a ground station of
its own), what MAVSDK was told.
"""

from __future__ import annotations

import asyncio
import math
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from bbcs.conf.parser import load_conf
from bbcs.testing import StepGate, wait_until

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "system"))
from mavlink_support import ROOT, Mav, first, gateway, run_async  # noqa: E402
from test_gcs_mission import GRID_DEG, ROBOT, SimRobot, connect, launch_robot  # noqa: E402

pytestmark = pytest.mark.timeout(240)
WATCH_S = 20.0
"""Simulated seconds watched after a flight task ends (the GRI state's stamps: the robot flies in lockstep)."""


def watch_quiet(robot: SimRobot, what: str) -> None:
    """For ``WATCH_S`` simulated seconds after ``what``, nothing reaches the DSP."""
    after, since = len(robot.commands()), robot.state.stamp
    robot.wait_state(lambda s: s.stamp >= since + WATCH_S, 120, f"{WATCH_S:g} simulated s after {what}")
    assert [c["name"] for c in robot.commands()[after:]] == [], f"the DSP received commands after {what}"


class Site:
    def __init__(self, robot: SimRobot, udp: int, tcp: int, gw: object, gate: StepGate) -> None:
        self.robot, self.udp, self.tcp, self.gw, self.gate = robot, udp, tcp, gw, gate


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Site]:
    tmp = tmp_path_factory.mktemp("uav")
    la, record = launch_robot(tmp, lockstep=True)
    gcs = gw = qgc = gate = None
    try:
        gcs = connect(la.port, "observer", link=False)
        gate = StepGate(gcs.session, ROBOT)
        gw, udp, tcp = gateway(la.port, "--manifest", str(ROOT / "bbcs_conf" / "uav1_sim.toml"), "-v")
        gw.wait_line(f"robot {ROBOT} is MAVLink system 1", 30)
        # an operator's ground station open throughout (QGroundControl's heartbeats): the gateway holds the robot's
        # link while one is heard, so the gaps between MAVSDK sessions are no link loss (test_secure.py has that)
        qgc = Mav(tcp, sysid=249, heartbeats=True)
        gw.wait_line(f"link to {ROBOT} held", 20)
        yield Site(SimRobot(la, gcs, record), udp, tcp, gw, gate)
    finally:
        if gate is not None:
            gate.leave()
        if qgc is not None:
            qgc.close()
        if gw is not None:
            gw.close()
            (tmp / "gateway.log").write_text("\n".join(gw.lines) + "\n")  # kept with the robot's logs
        if gcs is not None:
            gcs.close()
        la.stop()
        la.cleanup()


async def _system(udp: int):  # noqa: ANN202 - MAVSDK's types
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk

    m = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    await m.add_any_connection(f"udpin://127.0.0.1:{udp}")
    system = await m.first_autopilot(timeout_s=20.0)
    assert system is not None, "no MAVLink vehicle seen by MAVSDK"
    return m, system


def _metres(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    n = (lat2 - lat1) * 111_320.0
    e = (lon2 - lon1) * 111_320.0 * math.cos(math.radians(lat1))
    return math.hypot(n, e)


def test_connect_and_position_equals_the_gri(site: Site) -> None:
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    state = site.robot.wait_state(lambda s: s.position is not None and s.home is not None, 30, "a position")

    async def session():  # noqa: ANN202
        m, system = await _system(site.udp)
        try:
            assert await system.get_system_id() == 1
            tel = TelemetryAsync(system)
            pos = await first(tel.subscribe_position())
            home = await first(tel.subscribe_home())
            return (await system.vehicle_type()).name, pos, home
        finally:
            m.destroy()

    vehicle, pos, home = run_async(session, 60)
    now = site.robot.state.position
    assert now is not None and state.home is not None
    assert vehicle == "MULTICOPTER", vehicle  # MAVSDK's class of a MAV_TYPE_HELICOPTER (the heartbeat: below)
    assert _metres(pos.latitude_deg, pos.longitude_deg, now.lat, now.lon) < 1.0
    assert abs(pos.absolute_altitude_m - now.alt) < 1.0
    assert abs(pos.relative_altitude_m - (now.alt - state.home.alt)) < 1.0
    assert _metres(home.latitude_deg, home.longitude_deg, state.home.lat, state.home.lon) < 1.0


def _numbers(value: str | list[str]) -> int:
    """How many MAVLink parameters a .conf value is: each number of it, none if any of it is text."""
    values = value if isinstance(value, list) else [value]
    try:
        return len([float(v) for v in values])
    except ValueError:
        return 0


def test_parameter_list_is_the_conf_and_param_set_is_refused(site: Site) -> None:
    doc = load_conf(ROOT / "bbcs_conf" / "uav1.conf")
    mav = Mav(site.tcp)
    try:
        beat = mav.wait(0, "HEARTBEAT", sysid=1, timeout_s=15)
        assert beat.type == 4 and beat.autopilot == 0  # MAV_TYPE_HELICOPTER, MAV_AUTOPILOT_GENERIC
        mark = mav.mark()
        mav.mav.param_request_list_send(1, 1)
        first_value = mav.wait(mark, "PARAM_VALUE", timeout_s=15)
        count = first_value.param_count
        wait_until(lambda: len({m.param_index for m in mav.since(mark, "PARAM_VALUE")}) >= count, 15,
                   "every PARAM_VALUE")
        params = {m.param_id: m.param_value for m in mav.since(mark, "PARAM_VALUE")}
        assert sorted({m.param_index for m in mav.since(mark, "PARAM_VALUE")}) == list(range(count))
        # every numeric value of the .conf is there, each once: top-level keys, lists, groups
        numeric = sum(_numbers(e.value) for e in doc.entries.values())
        numeric += sum(_numbers(e.value) for g in doc.groups for e in g.entries.values())
        assert count == len(params) == numeric, (count, len(params), numeric)
        assert params["MAX_SPEED"] == 8.0 and params["TAKEOFF_HEIGHT"] == 10.0
        assert [params[f"GEOFENCE_{i}"] for i in (1, 2, 3)] == pytest.approx([37.4117, -6.0025, 3000.0])
        assert params["ROLL_KP"] == pytest.approx(0.045)

        mark = mav.mark()
        mav.mav.param_set_send(1, 1, b"MAX_SPEED", 12.0, 9)
        text = mav.wait(mark, "STATUSTEXT", lambda m: "MAX_SPEED" in m.text, 10)
        assert "refused" in text.text or text.id != 0
        echoed = mav.wait(mark, "PARAM_VALUE", lambda m: m.param_id == "MAX_SPEED", 10)
        assert echoed.param_value == 8.0, "PARAM_SET must change nothing"
        err = mav.wait(mark, "PARAM_ERROR", timeout_s=10)
        from pymavlink import mavutil

        assert err.error == mavutil.mavlink.MAV_PARAM_ERROR_READ_ONLY
    finally:
        mav.close()


def _grid(lat: float, lon: float) -> tuple[float, float]:
    return round(lat / GRID_DEG) * GRID_DEG, round(lon / GRID_DEG) * GRID_DEG


def test_fly_take_off_mission_gimbal_rtl_land(site: Site) -> None:
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.gimbal import GimbalAsync
    from mavsdk.asyncio.plugins.mission_raw import MissionItem, MissionRawAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
    from mavsdk.plugins.gimbal import GimbalMode, SendMode
    from mavsdk.plugins.mission_raw import MissionRawError

    robot = site.robot
    start = robot.wait_state(lambda s: s.position is not None and s.home is not None, 30, "a position")
    assert start.home is not None and not start.airborne
    home = start.home
    lat0, lon0 = _grid(home.lat, home.lon)
    rel = 15.0
    step = 3 * GRID_DEG  # legs of ~33 m: long enough to pause the mission in the middle of it
    path = [(lat0 + step, lon0), (lat0 + step, lon0 + step), (lat0 + 2 * step, lon0 + step), (lat0 + 2 * step, lon0)]

    def items(points: list[tuple[float, float]]) -> list:
        return [MissionItem(seq=i, frame=6, command=16, current=int(i == 0), autocontinue=1, param1=0.0,
                            param2=0.0, param3=0.0, param4=float("nan"), x=round(la * 1e7), y=round(lo * 1e7),
                            z=rel, mission_type=0) for i, (la, lo) in enumerate(points)]

    texts: list[str] = []

    async def session():  # noqa: ANN202
        m, system = await _system(site.udp)
        try:
            tel, act, mission = TelemetryAsync(system), ActionAsync(system), MissionRawAsync(system)

            async def collect() -> None:
                async for st in tel.subscribe_status_text():
                    texts.append(st.text)

            collector = asyncio.ensure_future(collect())
            # take-off: the DSP's take-off mode, flown to the .conf's TAKEOFF_HEIGHT
            mark = len(robot.commands())
            await act.takeoff()
            await first(tel.subscribe_position(), lambda p: p.relative_altitude_m > 8.0, 60)
            assert [c["fields"]["mode"] for c in robot.commands()[mark:] if c["name"] == "SET_MODE"] == [4]
            assert await first(tel.subscribe_in_air(), lambda x: x)

            # a mission outside the geofence: refused at start, with the RAL's reason, nothing sent to the DSP
            await mission.upload_mission(items([(lat0 + 0.032, lon0)]))  # 3.6 km: inside the range (5 km)
            mark = len(robot.commands())
            with pytest.raises(MissionRawError):
                await mission.start_mission()
            await asyncio.sleep(1.0)
            assert any("geofence" in t for t in texts), texts
            assert [c["name"] for c in robot.commands()[mark:]] == []

            # the mission: uploaded, started, flown; the DSP's queue holds exactly its waypoints, in order
            await mission.upload_mission(items(path))
            mark = len(robot.commands())
            await mission.start_mission()
            # paused once the first waypoint is reached (hold: ABORT at the DSP), then continued from where it was.
            # The simulation is held from the moment the test sees the waypoint reached until the hold reached the
            # DSP, so the pause lands on the leg the test chose at any load (at --speed max the aircraft flies on
            # while the pause crosses MAVSDK and the gateway on the wall clock). Under load MAVSDK also resends the
            # pause when its ACK is late: the resend must not move where the mission continues (test_vehicle.py)
            robot.wait_state(lambda s: 0 < (s.waypoints_queued or 0) < 4, 60, "the first waypoint reached")
            with site.gate.closed():
                # paused as a ground station pauses: once the gateway's own mission progress has the first waypoint
                # behind it. The gateway reads the robot's state on its own subscription, in no order with this
                # test's: paused on the test's word alone, it noted waypoint 0 and the continue re-flew all 4 (ci35:
                # one pause, no resend, in the gateway's log)
                await first(mission.subscribe_mission_progress(), lambda p: p.current >= 1, 30)
                await mission.pause_mission()
                wait_until(lambda: "ABORT" in [c["name"] for c in robot.commands()[mark:]], 15, "the hold's ABORT")
            await asyncio.sleep(1.0)
            await mission.start_mission()
            done = await first(mission.subscribe_mission_progress(), lambda p: p.total == 4 and p.current == 4, 90)
            assert done.current == 4
            return mark
        finally:
            collector.cancel()
            m.destroy()

    mark = run_async(session, 240)
    flown = robot.commands()[mark:]
    paused = [c["name"] for c in flown].index("ABORT")  # the hold
    added = [c["fields"] for c in flown[:paused] if c["name"] == "ADD_WAYPOINT"]
    planned = [(round(a, 4), round(b, 4)) for a, b in path]
    assert [(round(a["lat"], 4), round(a["lon"], 4)) for a in added] == planned
    names = [c["name"] for c in flown[paused:]]
    assert names.index("INVALIDATE_PATH") < names.index("ADD_WAYPOINT"), names
    again = [(round(c["fields"]["lat"], 4), round(c["fields"]["lon"], 4)) for c in flown[paused:]
             if c["name"] == "ADD_WAYPOINT"]
    assert 1 <= len(again) <= 3 and again == planned[-len(again):], again  # the rest of the mission, in order
    flown_home = robot.state.home  # the take-off point, as the RAL set it at the take-off
    assert flown_home is not None
    assert all(abs(a["alt"] - (flown_home.alt + rel)) < 0.01 for a in added), (added, flown_home)
    first_names = [c["name"] for c in flown[:paused]]
    assert first_names.index("INVALIDATE_PATH") < first_names.index("ADD_WAYPOINT")
    end = robot.wait_state(lambda s: s.waypoints_queued == 0, 20, "the queue empty")
    assert end.position is not None
    assert _metres(end.position.lat, end.position.lon, *path[-1]) < 8.0
    watch_quiet(robot, "the mission's end")  # nothing unrequested follows it
    assert not any(e.kind in ("failsafe", "task_failed") for e in robot.events), \
        "\n".join(f"{e.stamp:.2f} {e.kind} task {e.task_id} {e.detail}" for e in robot.events)  # every one, untruncated

    rtl_texts: list[str] = []

    async def gimbal_rtl_land():  # noqa: ANN202
        m, system = await _system(site.udp)
        try:
            tel, act, gimbal = TelemetryAsync(system), ActionAsync(system), GimbalAsync(system)

            async def collect() -> None:
                async for st in tel.subscribe_status_text():
                    rtl_texts.append(st.text)

            collector = asyncio.ensure_future(collect())
            mark = len(robot.commands())
            await gimbal.set_angles(0, 0.0, -30.0, 40.0, GimbalMode.YAW_FOLLOW, SendMode.ONCE)
            wait_until(lambda: any(c["name"] == "SET_PT_ANGLES" for c in robot.commands()[mark:]), 15,
                       "the gimbal angles at the DSP")
            pt = [c["fields"] for c in robot.commands()[mark:] if c["name"] == "SET_PT_ANGLES"][0]
            assert (round(pt["pan_deg"]), round(pt["tilt_deg"])) == (40, -30)

            # return to launch: home at the return altitude (above RETURN_HEIGHT already: no climb), then it lands
            # there by itself (RETURN_ACTION land), as a MAVLink user expects of RTL: no land command is sent
            mark = len(robot.commands())
            await act.return_to_launch()
            wait_until(lambda: any(c["name"] == "ADD_WAYPOINT" for c in robot.commands()[mark:]), 15, "RTL path")
            home_wp = [c["fields"] for c in robot.commands()[mark:] if c["name"] == "ADD_WAYPOINT"]
            assert len(home_wp) == 1 and _metres(home_wp[0]["lat"], home_wp[0]["lon"], home.lat, home.lon) < 12.0
            assert home_wp[0]["alt"] >= home.alt + 10.0 - 0.01
            await first(tel.subscribe_position(), lambda p: _metres(p.latitude_deg, p.longitude_deg, home.lat,
                                                                     home.lon) < 8.0, 60)
            await first(tel.subscribe_in_air(), lambda x: not x, 120)
            return mark
        finally:
            collector.cancel()
            m.destroy()

    mark = run_async(gimbal_rtl_land, 240)
    rtl = [(c["name"], c["fields"].get("mode")) for c in robot.commands()[mark:]]
    modes = [m for n, m in rtl if n == "SET_MODE"]
    assert modes[-1:] == [5] and modes.count(5) == 1, rtl  # one landing (the goto's waypoint mode before it)
    assert rtl.index(("ADD_WAYPOINT", None)) < rtl.index(("SET_MODE", 5)), rtl  # after the flight home
    assert any("home reached, landing" in x for x in rtl_texts), rtl_texts  # told as STATUSTEXT
    landed = robot.wait_state(lambda s: s.airborne is False, 30, "landed in the GRI")
    assert landed.position is not None
    assert _metres(landed.position.lat, landed.position.lon, home.lat, home.lon) < 8.0  # landed home
    watch_quiet(robot, "the landing")


def test_fence_upload_becomes_a_no_fly_zone_the_ral_enforces(site: Site) -> None:
    from mavsdk.asyncio.plugins.mission_raw import MissionItem, MissionRawAsync
    from mavsdk.plugins.mission_raw import MissionRawError

    from ral.gcs.fleet_cmd import world_snapshot

    robot = site.robot
    here = robot.wait_state(lambda s: s.position is not None, 30, "a position").position
    assert here is not None
    lat0, lon0 = _grid(here.lat, here.lon)
    square = [(lat0 + 2 * GRID_DEG, lon0 - GRID_DEG), (lat0 + 2 * GRID_DEG, lon0 + GRID_DEG),
              (lat0 + 4 * GRID_DEG, lon0 + GRID_DEG), (lat0 + 4 * GRID_DEG, lon0 - GRID_DEG)]
    fence = [MissionItem(seq=i, frame=0, command=5002, current=0, autocontinue=1, param1=4.0, param2=0.0,
                         param3=0.0, param4=0.0, x=round(la * 1e7), y=round(lo * 1e7), z=0.0, mission_type=1)
             for i, (la, lo) in enumerate(square)]
    across = [MissionItem(seq=0, frame=6, command=16, current=1, autocontinue=1, param1=0.0, param2=0.0, param3=0.0,
                          param4=0.0, x=round((lat0 + 6 * GRID_DEG) * 1e7), y=round(lon0 * 1e7), z=15.0,
                          mission_type=0)]
    texts: list[str] = []

    async def session():  # noqa: ANN202
        m, system = await _system(site.udp)
        try:
            from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

            tel, mission = TelemetryAsync(system), MissionRawAsync(system)

            async def collect() -> None:
                async for st in tel.subscribe_status_text():
                    texts.append(st.text)

            collector = asyncio.ensure_future(collect())
            await mission.upload_geofence(fence)
            zones = [e for e in world_snapshot(robot.gcs, ROBOT).entries if e.id.startswith("mavlink.") and
                     not e.deleted]
            assert [(e.id, type(e.body).__name__) for e in zones] == [("mavlink.uav1.fence0", "NoFlyZone")]
            await mission.upload_mission(across)  # from here to beyond the zone: its leg crosses it
            mark = len(robot.commands())
            with pytest.raises(MissionRawError):
                await mission.start_mission()
            await asyncio.sleep(1.0)
            assert any("no-fly zone" in x for x in texts), texts
            assert robot.commands()[mark:] == []
        finally:
            collector.cancel()
            m.destroy()

    run_async(session, 90)
    mav = Mav(site.tcp)  # MISSION_CLEAR_ALL of the fence (pymavlink): the vehicle's zones leave the world model
    try:
        mark = mav.mark()
        mav.mav.mission_clear_all_send(1, 1, 1)
        ack = mav.wait(mark, "MISSION_ACK", lambda m: m.mission_type == 1, 20)
        assert ack.type == 0  # MAV_MISSION_ACCEPTED
    finally:
        mav.close()
    gone = [e for e in world_snapshot(robot.gcs, ROBOT).entries if e.id.startswith("mavlink.")]
    assert gone and all(e.deleted for e in gone)


def test_signed_link_refuses_unsigned_forged_and_replayed_commands(site: Site, tmp_path: Path) -> None:
    key = os.urandom(32)
    key_file = tmp_path / "signing.key"
    key_file.write_bytes(key)
    gw, _udp, tcp = gateway(site.robot.launch.port, "--signing-key", str(key_file), "--name", "mavlink2")
    good = forged = unsigned = None
    try:
        gw.wait_line(f"robot {ROBOT} is MAVLink system 1", 30)
        good = Mav(tcp, sysid=251, key=key)
        forged = Mav(tcp, sysid=252, key=os.urandom(32))
        unsigned = Mav(tcp, sysid=253)
        wait_until(lambda: good.since(0, "HEARTBEAT"), 15, "signed heartbeats")
        assert all(m.get_signed() for m in good.since(0, "HEARTBEAT"))

        def pan_tilt(conn: Mav, pan: float) -> None:
            conn.mav.command_long_send(1, 1, 205, 0, -10.0, 0.0, pan, 0.0, 0.0, 0.0, 2.0)

        def angles(mark: int) -> list[float]:
            return [round(c["fields"]["pan_deg"]) for c in site.robot.commands()[mark:]
                    if c["name"] == "SET_PT_ANGLES"]

        # a genuine signed command goes through; its frame is kept to be replayed
        captured: list[bytes] = []
        orig_write = good.conn.write
        good.conn.write = lambda buf: (captured.append(bytes(buf)), orig_write(buf))[1]  # type: ignore[method-assign]
        mark, dsp = good.mark(), len(site.robot.commands())
        pan_tilt(good, 21.0)
        ack = good.wait(mark, "COMMAND_ACK", lambda m: m.command == 205, 15)
        assert ack.result == 0
        wait_until(lambda: 21 in angles(dsp), 15, "pan 21 at the DSP")
        good.conn.write = orig_write  # type: ignore[method-assign]
        frame = captured[-1]
        mark = good.mark()
        pan_tilt(good, 12.0)
        assert good.wait(mark, "COMMAND_ACK", lambda m: m.command == 205, 15).result == 0
        wait_until(lambda: angles(dsp)[-1:] == [12], 15, "pan 12 at the DSP")

        # every station gets every frame: the unsigned one reads both answers to the good one before its mark, so
        # anything it reads after the mark was sent after them
        wait_until(lambda: len([m for m in unsigned.since(0, "COMMAND_ACK") if m.target_system == 251]) == 2, 15,
                   "the unsigned station has read the good one's two answers")
        # the gateway signs all it sends: a station with the wrong key cannot read a frame of it
        assert not forged.since(0)

        # replayed (the captured pan 21), forged (a wrong key), unsigned: no answer, nothing at the DSP
        dsp, marks = len(site.robot.commands()), (good.mark(), unsigned.mark())
        good.conn.write(frame)
        pan_tilt(forged, 33.0)
        pan_tilt(unsigned, 44.0)
        time.sleep(3.0)
        assert not [m for m in good.since(marks[0], "COMMAND_ACK") if m.command == 205]
        assert not unsigned.since(marks[1], "COMMAND_ACK")
        assert not {21, 33, 44} & set(angles(dsp)), angles(dsp)
        assert site.robot.state.pan_deg is not None and abs(site.robot.state.pan_deg - 12.0) < 2.0
    finally:
        for conn in (good, forged, unsigned):
            if conn is not None:
                conn.close()
        gw.close()
    log = "\n".join(gw.lines)
    assert "replayed" in log and "bad signature" in log and "unsigned" in log, log


def test_a_qgroundcontrol_shaped_plan_takes_off_flies_returns_and_lands(site: Site) -> None:
    """A plan as QGroundControl makes one: take-off, waypoints, return to launch; started on the ground with MAVSDK's
    ``start_mission`` (AUTO.MISSION): the DSP gets the take-off, the path's waypoints in order, the way home and the
    landing, one after the other, and the robot ends on the ground at home."""
    from mavsdk.asyncio.plugins.mission_raw import MissionItem, MissionRawAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    robot = site.robot
    start = robot.wait_state(lambda s: s.position is not None and s.home is not None and s.airborne is False, 60,
                             "on the ground, its position known")
    assert start.home is not None and start.position is not None
    lat0, lon0 = _grid(start.position.lat, start.position.lon)
    path = [(lat0 + 2 * GRID_DEG, lon0), (lat0 + 2 * GRID_DEG, lon0 + 2 * GRID_DEG)]

    def item(seq: int, command: int, lat: float = 0.0, lon: float = 0.0, z: float = 0.0, frame: int = 6):
        return MissionItem(seq=seq, frame=frame, command=command, current=int(seq == 0), autocontinue=1, param1=0.0,
                           param2=0.0, param3=0.0, param4=float("nan"), x=round(lat * 1e7), y=round(lon * 1e7), z=z,
                           mission_type=0)

    plan = [item(0, 22, z=12.0), *[item(i + 1, 16, la, lo, 15.0) for i, (la, lo) in enumerate(path)], item(3, 20)]

    async def session():  # noqa: ANN202
        m, system = await _system(site.udp)
        try:
            tel, mission = TelemetryAsync(system), MissionRawAsync(system)
            await mission.upload_mission(plan)
            await mission.start_mission()
            await first(tel.subscribe_in_air(), lambda x: x, 30)
            await first(tel.subscribe_in_air(), lambda x: not x, 200)
        finally:
            m.destroy()

    mark = len(robot.commands())
    run_async(session, 240)
    flown = [(c["name"], c["fields"]) for c in robot.commands()[mark:]]
    modes = [f["mode"] for n, f in flown if n == "SET_MODE"]
    assert modes[0] == 4 and modes[-1] == 5, flown  # the take-off first, the landing last
    wps = [(round(f["lat"], 4), round(f["lon"], 4)) for n, f in flown if n == "ADD_WAYPOINT"]
    home = start.home
    assert wps[:2] == [(round(a, 4), round(b, 4)) for a, b in path], wps  # the plan's waypoints, in order
    assert _metres(*wps[-1], home.lat, home.lon) < 12.0, wps  # then home
    first_wp = next(i for i, (n, _) in enumerate(flown) if n == "ADD_WAYPOINT")
    land = max(i for i, (n, f) in enumerate(flown) if n == "SET_MODE" and f["mode"] == 5)
    take_off = min(i for i, (n, f) in enumerate(flown) if n == "SET_MODE" and f["mode"] == 4)
    assert take_off < first_wp < land
    landed = robot.wait_state(lambda s: s.airborne is False, 30, "landed in the GRI")
    assert landed.position is not None and _metres(landed.position.lat, landed.position.lon, home.lat,
                                                   home.lon) < 8.0
