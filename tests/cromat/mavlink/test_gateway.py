"""The gateway's loop (cromat/mavlink/gateway.py) between a stand-in ground-station API (the RAL's verdicts given by
hand) and an in-memory endpoint; the ground station's frames are pymavlink's own. Clock injected."""

from __future__ import annotations

import threading
from collections.abc import Callable

import msgspec
import pytest

from bbcs.contracts import gri
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.contracts.tasks import TaskInfo
from bbcs.testing import wait_until
from cromat.mavlink.dialect import mav
from cromat.mavlink.gateway import Gateway
from cromat.mavlink.vehicle import RobotSpec

AVAILABLE = {k: "movement" for k in ("take_off", "land", "goto", "follow_path", "hold")}


class StandInGcs:
    """What the gateway uses of ral.gcs.api.Gcs; ``verdict`` decides each request, ``release`` lets it answer."""

    name = "mavlink"

    def __init__(self) -> None:
        self.requests: list[gri.TaskRequest] = []
        self.verdict: Callable[[gri.TaskRequest], gri.TaskReply] = lambda r: gri.TaskReply(accepted=True, task_id=9)
        self.release = threading.Event()
        self.release.set()
        self.linked: list[str] = []
        self.on_state: Callable[[gri.GriState], None] = lambda s: None
        self.on_event: Callable[[gri.GriEvent], None] = lambda e: None

    def watch(self, robot: str, callback: Callable[[gri.GriState], None]) -> None:
        self.on_state = callback

    def hold_link(self, robot: str) -> None:
        self.linked.append(robot)

    def release_link(self, robot: str) -> None:
        self.linked.remove(robot)

    def events(self, robot: str, callback: Callable[[gri.GriEvent], None]) -> None:
        self.on_event = callback

    def send(self, robot: str, request: gri.TaskRequest) -> gri.TaskReply:
        self.requests.append(request)
        self.release.wait(10)
        return self.verdict(request)


class Wire:
    """An endpoint in memory: what the gateway sends, parsed by pymavlink."""

    name = "memory"

    def __init__(self) -> None:
        self.received: Callable[[str, bytes], None] | None = None
        self.parser = mav.MAVLink(None, 255, 190)
        self.client = mav.MAVLink(None, 255, 190)
        self.out: list[object] = []

    def start(self, received: Callable[[str, bytes], None]) -> None:
        self.received = received

    def send(self, frame: bytes) -> None:
        self.out += [m for m in self.parser.parse_buffer(frame) or [] if m.get_type() != "BAD_DATA"]

    def close(self) -> None:
        pass

    def write(self, msg: object) -> None:
        assert self.received is not None
        self.received("memory:gcs", msg.pack(self.client))  # type: ignore[attr-defined]
        self.client.seq = (self.client.seq + 1) % 256

    def of(self, kind: str) -> list:
        return [m for m in self.out if m.get_type() == kind]

    def texts(self) -> list[str]:
        """STATUSTEXTs as read: chunks of one id joined (MAVLink 2)."""
        joined: dict[object, str] = {}
        for i, m in enumerate(self.of("STATUSTEXT")):
            key = m.id if m.id else ("single", i)
            joined[key] = joined.get(key, "") + m.text
        return list(joined.values())


def state(tasks: list[TaskInfo] | None = None, queued: int = 0) -> gri.GriState:
    tel = RobotTelemetry(stamp=1.0, position=GeoPoint(lat=37.4117, lon=-6.0025, alt=27.0), airborne=True,
                         waypoints_queued=queued)
    return gri.GriState(robot="uav1", kind="uav", stamp=1.0, telemetry=tel, tasks=tasks or [], available=AVAILABLE,
                        home=GeoPoint(lat=37.4117, lon=-6.0025, alt=12.0), manager_up=True)


def setup() -> tuple[Gateway, StandInGcs, Wire, list[float]]:
    now = [100.0]
    gcs, wire = StandInGcs(), Wire()
    gw = Gateway(gcs, [wire], [RobotSpec(name="uav1", sysid=3)], discover=False, clock=lambda: now[0])  # type: ignore[arg-type]
    gw.start()
    gcs.on_state(state())
    gw.turn(0.0)
    return gw, gcs, wire, now


def pump(gw: Gateway, until: Callable[[], bool], what: str) -> None:
    def step() -> bool:
        gw.turn(0.01)
        return until()

    wait_until(step, 5, what)


def test_a_command_is_the_rals_verdict_and_a_refusal_says_why() -> None:
    gw, gcs, wire, _ = setup()
    assert wire.of("HEARTBEAT")[0].get_srcSystem() == 3
    wire.write(mav.MAVLink_command_long_message(3, 1, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0))
    pump(gw, lambda: bool(wire.of("COMMAND_ACK")), "the land's ACK")
    assert gcs.requests == [gri.Land()] and wire.of("COMMAND_ACK")[0].result == mav.MAV_RESULT_ACCEPTED
    gcs.verdict = lambda r: gri.TaskReply(accepted=False, reason="the ceiling is 120 m")
    wire.write(mav.MAVLink_command_long_message(3, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 500.0))
    pump(gw, lambda: len(wire.of("COMMAND_ACK")) == 2, "the take-off's ACK")
    assert wire.of("COMMAND_ACK")[1].result == mav.MAV_RESULT_DENIED
    assert any("take_off refused: the ceiling is 120 m" in t for t in wire.texts())
    # another system's command, and a command to nobody: neither reaches the RAL
    wire.write(mav.MAVLink_command_long_message(4, 1, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0))
    wire.write(mav.MAVLink_command_long_message(0, 0, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0))
    gw.turn(0.05)
    assert len(gcs.requests) == 2


def test_a_resent_command_is_in_progress_not_sent_twice() -> None:
    gw, gcs, wire, _ = setup()
    gcs.release.clear()  # the RAL takes its time
    cmd = mav.MAVLink_command_long_message(3, 1, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0)
    wire.write(cmd)
    pump(gw, lambda: len(gcs.requests) == 1, "the request at the RAL")
    wire.write(mav.MAVLink_command_long_message(3, 1, mav.MAV_CMD_NAV_LAND, 1, 0, 0, 0, 0, 0, 0, 0))
    pump(gw, lambda: bool(wire.of("COMMAND_ACK")), "an answer to the resend")
    assert wire.of("COMMAND_ACK")[0].result == mav.MAV_RESULT_IN_PROGRESS and len(gcs.requests) == 1
    # a different command of the same number is a new request, not a resend
    wire.write(mav.MAVLink_command_long_message(3, 1, mav.MAV_CMD_DO_REPOSITION, 0, -1, 0, 0, 0, 37.42, -6.0, 30.0))
    wire.write(mav.MAVLink_command_long_message(3, 1, mav.MAV_CMD_DO_REPOSITION, 0, -1, 0, 0, 0, 37.43, -6.0, 30.0))
    gcs.release.set()
    pump(gw, lambda: len(wire.of("COMMAND_ACK")) == 4, "the verdicts")
    assert [a.result for a in wire.of("COMMAND_ACK")[1:]] == [mav.MAV_RESULT_ACCEPTED] * 3
    lats = [r.waypoints[0].lat for r in gcs.requests[1:]]  # type: ignore[union-attr]
    assert lats == pytest.approx([37.42, 37.43], abs=1e-5)  # COMMAND_LONG's params are float32


def upload(gw: Gateway, wire: Wire, n: int) -> None:
    wire.write(mav.MAVLink_mission_count_message(3, 1, n, 0))
    for seq in range(n):
        pump(gw, lambda s=seq: any(r.seq == s for r in wire.of("MISSION_REQUEST_INT")), f"request {seq}")
        wire.write(mav.MAVLink_mission_item_int_message(3, 1, seq, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                                        mav.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, 0,
                                                        374117000 + 3000 * seq, -60025000, 15.0, 0))


def test_a_mission_uploaded_while_one_flies_replaces_its_path_with_the_rals_verdict() -> None:
    gw, gcs, wire, _ = setup()
    upload(gw, wire, 2)
    pump(gw, lambda: bool(wire.of("MISSION_ACK")), "the upload's ACK")
    assert wire.of("MISSION_ACK")[0].type == mav.MAV_MISSION_ACCEPTED and gcs.requests == []  # stored, not flown
    wire.write(mav.MAVLink_command_long_message(3, 1, mav.MAV_CMD_MISSION_START, 0, 0, 0, 0, 0, 0, 0, 0))
    pump(gw, lambda: bool(wire.of("COMMAND_ACK")), "the start's ACK")
    path = gcs.requests[0]
    assert isinstance(path, gri.FollowPath) and [w.alt for w in path.waypoints] == [27.0, 27.0]
    gcs.on_state(state([TaskInfo(id=9, name="follow_path", task_type="movement", kind="follow_path", params=path)],
                       queued=2))
    gw.turn(0.0)
    # a new mission while the first flies: its MISSION_ACK waits for the RAL, which refuses it here
    gcs.verdict = lambda r: gri.TaskReply(accepted=False, reason="waypoint 2 is outside the geofence")
    wire.out.clear()
    upload(gw, wire, 3)
    pump(gw, lambda: bool(wire.of("MISSION_ACK")), "the second upload's ACK")
    assert len(gcs.requests) == 2 and len(gcs.requests[1].waypoints) == 3  # type: ignore[union-attr]
    assert wire.of("MISSION_ACK")[0].type == mav.MAV_MISSION_DENIED
    assert any("mission refused: waypoint 2 is outside the geofence" in t for t in wire.texts())
    assert gw.vehicles["uav1"].plan is not None and len(gw.vehicles["uav1"].plan.waypoints) == 2  # the old one kept


def test_a_lost_mission_item_is_asked_again_on_the_clock() -> None:
    gw, gcs, wire, now = setup()
    wire.write(mav.MAVLink_mission_count_message(3, 1, 2, 0))
    pump(gw, lambda: len(wire.of("MISSION_REQUEST_INT")) == 1, "the first request")
    now[0] += 1.6
    gw.turn(0.0)
    assert [r.seq for r in wire.of("MISSION_REQUEST_INT")] == [0, 0]


def test_parameters_and_a_refused_set() -> None:
    gw, gcs, wire, _ = setup()
    wire.write(mav.MAVLink_param_request_list_message(3, 1))
    gw.turn(0.05)
    assert wire.of("PARAM_VALUE") == []  # no manifest given: no parameters
    wire.write(mav.MAVLink_param_set_message(3, 1, b"MAX_SPEED", 3.0, mav.MAV_PARAM_TYPE_REAL32))
    pump(gw, lambda: bool(wire.of("PARAM_ERROR")), "the refusal")
    assert wire.of("PARAM_ERROR")[0].error == mav.MAV_PARAM_ERROR_DOES_NOT_EXIST
    assert any("no such parameter" in t for t in wire.texts())


def gcs_heartbeat(kind: int = mav.MAV_TYPE_GCS) -> object:
    return mav.MAVLink_heartbeat_message(kind, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE, 3)


def test_the_link_is_held_only_while_a_mavlink_ground_station_is_heard() -> None:
    gw, gcs, wire, now = setup()
    assert gcs.linked == []  # served, its telemetry sent, but no operator yet: the robot's failsafe is not armed
    wire.write(gcs_heartbeat(mav.MAV_TYPE_QUADROTOR))  # another vehicle's heartbeat is no ground station
    gw.turn(0.05)
    assert gcs.linked == []
    wire.write(gcs_heartbeat())
    gw.turn(0.05)
    assert gcs.linked == ["uav1"]
    now[0] += 2.9  # quiet, but within the timeout
    gw.turn(0.0)
    assert gcs.linked == ["uav1"]
    now[0] += 0.2  # three heartbeats missed: the ground station is gone, the robot's link with it
    gw.turn(0.0)
    assert gcs.linked == []
    wire.write(gcs_heartbeat())  # back
    gw.turn(0.05)
    assert gcs.linked == ["uav1"]


def test_a_return_to_launch_lands_once_home_is_reached() -> None:
    gw, gcs, wire, _ = setup()
    gcs.verdict = lambda r: gri.TaskReply(accepted=True, task_id=11 if isinstance(r, gri.Goto) else 12)
    wire.write(mav.MAVLink_command_long_message(3, 1, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0))
    pump(gw, lambda: bool(wire.of("COMMAND_ACK")), "the RTL's ACK")
    assert isinstance(gcs.requests[0], gri.Goto) and wire.of("COMMAND_ACK")[0].result == mav.MAV_RESULT_ACCEPTED
    # another task's end is not the return's
    gcs.on_event(gri.GriEvent(robot="uav1", stamp=2.0, kind="task_completed", task_id=9))
    gw.turn(0.05)
    assert len(gcs.requests) == 1
    gcs.on_event(gri.GriEvent(robot="uav1", stamp=3.0, kind="task_completed", task_id=11))
    pump(gw, lambda: any("home reached, landing" in t for t in wire.texts()), "the landing told")
    assert gcs.requests[1:] == [gri.Land()]
    assert gw.vehicles["uav1"].rtl_task == 12  # the landing is shown as the return's (RTL mode)
    gcs.on_event(gri.GriEvent(robot="uav1", stamp=4.0, kind="task_completed", task_id=12))
    gw.turn(0.05)
    assert len(gcs.requests) == 2  # landed: nothing more


def test_a_return_that_does_not_complete_does_not_land_and_hover_holds() -> None:
    gw, gcs, wire, _ = setup()
    gcs.verdict = lambda r: gri.TaskReply(accepted=True, task_id=11)
    wire.write(mav.MAVLink_command_long_message(3, 1, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0))
    pump(gw, lambda: bool(wire.of("COMMAND_ACK")), "the RTL's ACK")
    gcs.on_event(gri.GriEvent(robot="uav1", stamp=2.0, kind="task_replaced", task_id=11))
    gw.turn(0.05)
    assert len(gcs.requests) == 1
    gw.vehicles["uav1"].spec.return_action = "hover"  # the .conf's RETURN_ACTION: hover
    wire.write(mav.MAVLink_command_long_message(3, 1, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 1))
    pump(gw, lambda: len(wire.of("COMMAND_ACK")) == 2, "the second RTL's ACK")
    gcs.on_event(gri.GriEvent(robot="uav1", stamp=3.0, kind="task_completed", task_id=11))
    pump(gw, lambda: any("holding there" in t for t in wire.texts()), "the hover told")
    assert len(gcs.requests) == 2 and all(isinstance(r, gri.Goto) for r in gcs.requests)


def test_a_plan_with_take_off_and_return_is_a_sequence_of_gri_tasks() -> None:
    gw, gcs, wire, _ = setup()
    gcs.on_state(msgspec.structs.replace(state(), telemetry=msgspec.structs.replace(state().telemetry,
                                                                                    airborne=False)))
    ids = {gri.TakeOff: 21, gri.FollowPath: 22, gri.Goto: 23, gri.Land: 24}
    gcs.verdict = lambda r: gri.TaskReply(accepted=True, task_id=ids[type(r)])
    rel = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    items = [mav.MAVLink_mission_item_int_message(3, 1, 0, rel, mav.MAV_CMD_NAV_TAKEOFF, 0, 1, 0, 0, 0, 0, 0, 0,
                                                  12.0, 0)]
    items += [mav.MAVLink_mission_item_int_message(3, 1, seq, rel, mav.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, 0,
                                                   374117000 + 3000 * seq, -60025000, 15.0, 0) for seq in (1, 2)]
    items += [mav.MAVLink_mission_item_int_message(3, 1, 3, mav.MAV_FRAME_MISSION, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH,
                                                   0, 1, 0, 0, 0, 0, 0, 0, 0, 0)]
    wire.write(mav.MAVLink_mission_count_message(3, 1, len(items), 0))
    for it in items:
        pump(gw, lambda s=it.seq: any(r.seq == s for r in wire.of("MISSION_REQUEST_INT")), f"request {it.seq}")
        wire.write(it)
    pump(gw, lambda: bool(wire.of("MISSION_ACK")), "the upload's ACK")
    assert wire.of("MISSION_ACK")[0].type == mav.MAV_MISSION_ACCEPTED
    wire.write(mav.MAVLink_command_long_message(3, 1, mav.MAV_CMD_MISSION_START, 0, 0, 0, 0, 0, 0, 0, 0))
    pump(gw, lambda: bool(wire.of("COMMAND_ACK")), "the start's ACK")
    assert gcs.requests == [gri.TakeOff(height=12.0)]  # on the ground: the take-off item first
    gcs.on_event(gri.GriEvent(robot="uav1", stamp=2.0, kind="task_completed", task_id=21))
    pump(gw, lambda: len(gcs.requests) == 2, "the path after the take-off")
    path = gcs.requests[1]
    assert isinstance(path, gri.FollowPath) and [w.alt for w in path.waypoints] == [27.0, 27.0]
    pump(gw, lambda: any("take-off done, flying the mission" in t for t in wire.texts()), "told")
    gcs.on_event(gri.GriEvent(robot="uav1", stamp=3.0, kind="task_completed", task_id=22))
    pump(gw, lambda: len(gcs.requests) == 3, "the return after the path")
    assert isinstance(gcs.requests[2], gri.Goto)
    gcs.on_event(gri.GriEvent(robot="uav1", stamp=4.0, kind="task_completed", task_id=23))
    pump(gw, lambda: len(gcs.requests) == 4, "the return's landing")
    assert gcs.requests[3] == gri.Land()
    assert len(wire.of("COMMAND_ACK")) == 1  # one command, one ACK: the rest told as STATUSTEXT


def test_a_mission_whose_take_off_fails_flies_nothing_more() -> None:
    gw, gcs, wire, _ = setup()
    gcs.on_state(msgspec.structs.replace(state(), telemetry=msgspec.structs.replace(state().telemetry,
                                                                                    airborne=False)))
    gcs.verdict = lambda r: gri.TaskReply(accepted=True, task_id=21)
    rel = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    items = [mav.MAVLink_mission_item_int_message(3, 1, 0, rel, mav.MAV_CMD_NAV_TAKEOFF, 0, 1, 0, 0, 0, 0, 0, 0,
                                                  12.0, 0),
             mav.MAVLink_mission_item_int_message(3, 1, 1, rel, mav.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, 0,
                                                  374120000, -60025000, 15.0, 0)]
    wire.write(mav.MAVLink_mission_count_message(3, 1, 2, 0))
    for it in items:
        pump(gw, lambda s=it.seq: any(r.seq == s for r in wire.of("MISSION_REQUEST_INT")), f"request {it.seq}")
        wire.write(it)
    pump(gw, lambda: bool(wire.of("MISSION_ACK")), "the upload's ACK")
    wire.write(mav.MAVLink_command_long_message(3, 1, mav.MAV_CMD_MISSION_START, 0, 0, 0, 0, 0, 0, 0, 0))
    pump(gw, lambda: bool(wire.of("COMMAND_ACK")), "the start's ACK")
    gcs.on_event(gri.GriEvent(robot="uav1", stamp=2.0, kind="task_failed", task_id=21))
    gw.turn(0.1)
    assert gcs.requests == [gri.TakeOff(height=12.0)]
