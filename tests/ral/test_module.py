"""The RAL process's request/reply handling on real Zenoh, against a stand-in Module Manager queryable.

This is not the system test (that one runs the real manager, see test_system.py): the stand-in only answers
MRI requests per module_manager/mri.py and publishes a RobotState, so the RAL's own behaviour is checked:
admission and rejection, MRI requests sent, data slots published, events, completion and the failsafe.
"""

from __future__ import annotations

import itertools
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgspec
import pytest
import zenoh

from bbcs import keys
from bbcs.context import ModuleContext
from bbcs.contracts import gri, mri
from bbcs.contracts.path_follower import DatosSegCam, SpeedSegCam
from bbcs.contracts.robot import GeoPoint, RobotTelemetry
from bbcs.session import local_client, open_session
from bbcs.testing import wait_until
from ral.gcs.api import Gcs
from ral.module import Ral

sys.path.insert(0, str(Path(__file__).resolve().parent))
from standin import ROBOT, StandIn  # noqa: E402


@dataclass
class Rig:
    port: int
    ral: Ral
    manager: StandIn
    gcs: Gcs
    events: list[gri.GriEvent]
    states: list[gri.GriState]

    def kinds(self) -> list[str]:
        return [e.kind for e in list(self.events)]


@pytest.fixture
def rig(router: int, request: pytest.FixtureRequest) -> Iterator[Rig]:
    manager_session = open_session(local_client(router))
    manager = StandIn(manager_session)
    manager.start()
    params = {
        "failsafe_timeout_s": "0.6",
        # a GCS heartbeats every 0.5 s: a timeout of 0.5 s would flap the link on a loaded machine; link loss
        # here comes from the link GCS closing (its liveliness token goes), which this timeout does not delay
        "heartbeat_timeout_s": "3",
        "regain_s": "0.2",
        "state_period_s": "0.05",
        "settle_s": "0",
        "failsafe_action": "hold",
        "speed_ack_from": "path_follower",  # the stand-in answers speeds as the UAV's path follower does
    }
    wired = request.node.get_closest_marker("ral_params")  # a test's own RAL parameters on top
    params.update(wired.kwargs if wired is not None else {})
    ral = Ral(ModuleContext(robot=ROBOT, module="ral", bus=local_client(router), params=params))
    thread = threading.Thread(target=ral.run, daemon=True)
    thread.start()
    gcs = None
    try:
        gcs = Gcs(local_client(router), name="station", timeout_s=10.0)
        events: list[gri.GriEvent] = []
        states: list[gri.GriState] = []
        gcs.events(ROBOT, events.append)
        gcs.watch(ROBOT, states.append)
        wait_until(lambda: any(s.available for s in states), 30, "RAL state with the task list")
        yield Rig(router, ral, manager, gcs, events, states)
    finally:
        if gcs is not None:
            gcs.close()
        ral.request_stop()
        thread.join(10)
        manager.close()
        manager_session.close()
    assert not thread.is_alive()


def ten_waypoints() -> gri.Goto:
    return gri.Goto(
        waypoints=[gri.Waypoint(lat=37.41 + 0.0002 * i, lon=-6.0, alt=30.0) for i in range(10)], speed=4.0
    )


def test_goto_is_sent_to_the_manager_published_and_completed_from_telemetry(rig: Rig) -> None:
    paths: list[DatosSegCam] = []
    sub = rig.gcs.session.declare_subscriber(
        keys.slot_key(ROBOT, "ral", "path"),
        lambda s: paths.append(msgspec.msgpack.decode(s.payload.to_bytes(), type=DatosSegCam)),
    )
    try:
        task = ten_waypoints()
        reply = rig.gcs.send(ROBOT, task)
        assert reply.accepted and reply.task_type == "movement" and reply.task_id > 0
        sent = rig.manager.set_tasks()[-1]
        assert (sent.name, sent.params, sent.origin) == ("goto", task, "gcs"), "the typed task travels to the manager"
        assert set(sent.data) == {"speed", "path"}, "its data go with it, for the manager to carry in the mode"
        assert msgspec.msgpack.decode(sent.data["speed"], type=SpeedSegCam) == SpeedSegCam(speed=4.0)
        assert msgspec.msgpack.decode(sent.data["path"], type=DatosSegCam).n_points == 10
        wait_until(lambda: len(paths) == 1, what="path on ral/path")
        assert paths[0].n_points == 10 and paths[0].puntos[-1].latitud == task.waypoints[-1].lat
        wait_until(
            lambda: any(t.id == reply.task_id for s in rig.states[-3:] for t in s.tasks),
            what="task in the GRI state",
        )
        last = task.waypoints[-1]
        rig.manager.telemetry(
            RobotTelemetry(
                stamp=1.0, position=GeoPoint(lat=37.41, lon=-6.0, alt=30.0), waypoints_queued=9, airborne=True
            )
        )
        rig.manager.telemetry(
            RobotTelemetry(
                stamp=2.0,
                position=GeoPoint(lat=last.lat, lon=last.lon, alt=30.5),
                waypoints_queued=0,
                airborne=True,
            )
        )
        wait_until(lambda: "task_completed" in rig.kinds(), what="task_completed event")
        done = next(e for e in rig.events if e.kind == "task_completed")
        assert done.task_id == reply.task_id
        assert rig.manager.end_tasks()[-1] == mri.EndTask(
            task_type="movement", task_id=reply.task_id, status="completed", detail=""
        ), "the RAL's verdict goes to the manager's task book"
        wait_until(
            lambda: rig.states[-1].tasks == [] and rig.states[-1].telemetry is not None,
            what="state without the task",
        )
    finally:
        sub.undeclare()


def test_bad_tasks_are_rejected_with_a_reason_and_change_nothing(rig: Rig) -> None:
    out_of_range = gri.Goto(waypoints=[gri.Waypoint(lat=95.0, lon=0.0, alt=10.0)])
    reply = rig.gcs.send(ROBOT, out_of_range)
    assert not reply.accepted and "lat" in reply.reason and "<= 90" in reply.reason
    unknown = [
        r
        for r in rig.gcs.session.get(
            gri.task_key(ROBOT), payload=msgspec.msgpack.encode({"type": "teleport"}), timeout=10.0
        )
        if r.ok is not None
    ]
    assert len(unknown) == 1
    decoded = gri.decode_reply(unknown[0].ok.payload.to_bytes())
    assert not decoded.accepted and "teleport" in decoded.reason
    lacking = rig.gcs.send(ROBOT, gri.FollowPath(waypoints=ten_waypoints().waypoints))
    assert not lacking.accepted and "no task 'follow_path'" in lacking.reason
    assert rig.manager.set_tasks() == []
    wait_until(lambda: rig.kinds().count("task_rejected") == 3, what="three task_rejected events")
    assert rig.states[-1].tasks == []


@pytest.mark.ral_params(planner="", refs_to="")
def test_a_task_whose_module_the_manifest_does_not_wire_is_refused_before_anything_starts(rig: Rig) -> None:
    """The RAL's planner and bridge modules are manifest parameters (issue 35: keys wired by the manifest); a robot
    without them (the uQuad) refuses a survey, an orbit and a bridge with the reason, and asks the manager nothing."""
    survey = gri.Survey(polygon=[gri.Vertex(lat=37.41, lon=-6.0), gri.Vertex(lat=37.411, lon=-6.0),
                                 gri.Vertex(lat=37.411, lon=-6.001)], height=20.0)
    orbit = gri.Orbit(lat=37.41, lon=-6.0, radius=30.0)
    for task in (survey, orbit):
        reply = rig.gcs.send(ROBOT, task)
        assert not reply.accepted and "has no path planner" in reply.reason and "planner" in reply.reason
    reply = rig.gcs.send(ROBOT, gri.Bridge(ref_altitude=40.0))
    assert not reply.accepted and "refs_to" in reply.reason
    assert rig.manager.set_tasks() == []
    wait_until(lambda: rig.kinds().count("task_rejected") == 3, what="three task_rejected events")


def test_manager_refusal_is_passed_on(rig: Rig) -> None:
    rig.manager.refuse = "module pan_tilt is failed"
    reply = rig.gcs.send(ROBOT, gri.SetPanTilt(pan=10.0, tilt=-10.0))
    assert not reply.accepted and "module pan_tilt is failed" in reply.reason
    assert reply.code == 117, "the refusing module's code reaches the ground station"
    wait_until(lambda: any(e.module == "ral" for e in rig.states[-1].errors), what="error in the GRI state")


def test_abort_ends_every_task(rig: Rig) -> None:
    goto = rig.gcs.send(ROBOT, ten_waypoints())
    look = rig.gcs.send(ROBOT, gri.LookAt(lat=37.0, lon=-6.0, alt=0.0))
    assert goto.accepted and look.accepted
    reply = rig.gcs.abort(ROBOT)
    assert reply.accepted, reply.reason
    after = rig.manager.requests[-3:]
    assert after[:2] == [
        mri.SetTask(name="abort", origin="gcs", replaced_as="aborted"),
        mri.EndTask(task_type="pan_tilt", status="aborted", detail="abort"),
    ]
    assert isinstance(after[2], mri.EndTask) and after[2].status == "completed", "the abort task ends once done"
    wait_until(lambda: {e.task_id for e in list(rig.events) if e.kind == "aborted"} == {goto.task_id, look.task_id},
               what="an aborted event for each running task")
    wait_until(lambda: rig.states[-1].tasks == [], what="no task in the state")


def test_cancel_ends_one_type(rig: Rig) -> None:
    assert rig.gcs.send(ROBOT, gri.SetPanTilt(pan=1.0, tilt=2.0)).accepted
    reply = rig.gcs.send(ROBOT, gri.Cancel(task_type="pan_tilt"))
    assert reply.accepted
    assert rig.manager.requests[-1] == mri.EndTask(task_type="pan_tilt", status="cancelled", detail="cancelled")
    wait_until(lambda: "task_cancelled" in rig.kinds(), what="task_cancelled event")
    bad = rig.gcs.send(ROBOT, gri.Cancel(task_type="swimming"))
    assert not bad.accepted and "swimming" in bad.reason


def test_link_loss_runs_the_failsafe_and_regain_does_not_resume(rig: Rig) -> None:
    link = Gcs(local_client(rig.port), name="pilot", link=[ROBOT])
    try:
        wait_until(lambda: "link_up" in rig.kinds(), what="link_up")
        assert rig.gcs.send(ROBOT, ten_waypoints()).accepted
    finally:
        link.close()
    wait_until(lambda: "link_lost" in rig.kinds(), what="link_lost")
    wait_until(lambda: "failsafe" in rig.kinds(), what="failsafe event")
    wait_until(
        lambda: rig.manager.set_tasks()[-1] == mri.SetTask(name="hold", params=gri.Hold(), origin="failsafe"),
        what="hold sent to the manager",
    )
    # the stand-in sees the request before the RAL hears the reply: wait for the GRI state to show it too
    wait_until(lambda: any(t.kind == "hold" and t.origin == "failsafe" for t in rig.states[-1].tasks),
               what="the failsafe hold shown as the current task")
    sent = len(rig.manager.set_tasks())
    back = Gcs(local_client(rig.port), name="pilot", link=[ROBOT])
    try:
        wait_until(lambda: "link_regained" in rig.kinds(), what="link_regained")
        regained = next(e for e in rig.events if e.kind == "link_regained")
        assert "stays in force" in regained.detail
        wait_until(lambda: rig.states[-1].link == "up", what="link up in the state")
        # a task through the RAL's one worker queue, sent after that state was published: anything the regain
        # queued for the manager (a resumed mission) is sent before it, so only this one may follow the hold
        assert rig.gcs.send(ROBOT, gri.SetPanTilt(pan=1.0, tilt=2.0)).accepted
        assert [r.name for r in rig.manager.set_tasks()[sent:]] == ["pan_tilt"], "the mission resumed on regain"
    finally:
        back.close()


def test_an_operator_task_after_the_failsafe_clears_it_for_fleet_bids_too(rig: Rig) -> None:  # issue 30 case 6
    link = Gcs(local_client(rig.port), name="pilot", link=[ROBOT])
    try:
        wait_until(lambda: "link_up" in rig.kinds(), what="link_up")
    finally:
        link.close()
    wait_until(lambda: rig.states[-1].link == "failsafe", what="the failsafe in force")
    assert not rig.ral._fleet_own().available  # a fleet task now: "its own failsafe is in force"
    assert rig.gcs.send(ROBOT, gri.SetPanTilt(pan=1.0, tilt=2.0)).accepted  # one-shot: no link held
    wait_until(lambda: rig.states[-1].link == "no_gcs", what="the failsafe cleared in the state")
    assert rig.ral._fleet_own().available
    time.sleep(1.0)  # failsafe_timeout_s is 0.6 s: nothing armed again without a new link
    assert rig.states[-1].link == "no_gcs" and rig.kinds().count("failsafe") == 1


def test_robots_lists_the_ral(rig: Rig) -> None:
    assert rig.gcs.robots() == [ROBOT]
    assert rig.gcs.state(ROBOT).robot == ROBOT


def test_a_lost_effect_fails_the_task_with_a_reason(rig: Rig) -> None:
    """Supervision: a module error after the task started, and a manager restart (new task-book epoch)."""
    goto = rig.gcs.send(ROBOT, ten_waypoints())
    assert goto.accepted
    rig.manager.publish_state(
        modules=[mri.ModuleStatus(name="path_follower", state="up", task_types=["movement"])],
        errors=[mri.ErrorEvent(module="path_follower", code=1007, stamp=10.0, name="DSP_LOW_BATTERY")],
    )
    wait_until(lambda: any(e.kind == "task_failed" and e.task_id == goto.task_id for e in list(rig.events)),
               what="task_failed after a module error")
    failed = next(e for e in rig.events if e.kind == "task_failed")
    assert "path_follower" in failed.detail and "1007" in failed.detail
    assert rig.manager.end_tasks()[-1].status == "failed" and rig.manager.end_tasks()[-1].task_id == goto.task_id
    look = rig.gcs.send(ROBOT, gri.LookAt(lat=37.41, lon=-6.0, alt=12.0))
    assert look.accepted
    rig.manager.epoch = 2.0  # the manager restarted: its book no longer holds the look_at
    rig.manager.book = type(rig.manager.book)(rig.manager.book.tasks)
    rig.manager.publish_state()
    wait_until(lambda: any(e.kind == "task_failed" and e.task_id == look.task_id for e in list(rig.events)),
               what="task_failed after a manager restart")
    assert "Module Manager restarted" in next(e for e in rig.events if e.task_id == look.task_id
                                              and e.kind == "task_failed").detail


def test_data_the_managers_modes_carried_are_not_published_again(rig: Rig) -> None:
    """The four-hop path (docs/bus.md, "The command path"): when the manager says the task's modes carried its
    speed and path, the RAL publishes neither (the path follower would fly the path twice) and waits for no speed
    answer; the task data (TaskData) still go out for the modules that read tasks whole."""
    seen: list[str] = []
    subs = [rig.gcs.session.declare_subscriber(keys.slot_key(ROBOT, "ral", slot), lambda s, n=slot: seen.append(n))
            for slot in ("speed", "path", "task")]
    rig.manager.carry = True
    rig.manager.answer_speed = False  # nothing answers a published speed: the task is accepted without one
    try:
        reply = rig.gcs.send(ROBOT, ten_waypoints())
        assert reply.accepted, reply.reason
        assert set(rig.manager.set_tasks()[-1].data) == {"speed", "path"}
        wait_until(lambda: "task" in seen, what="the task's TaskData")
        time.sleep(0.5)
        assert seen == ["task"], f"published besides the carried data: {seen}"
    finally:
        for sub in subs:
            sub.undeclare()


def test_a_path_whose_speed_the_path_follower_never_answers_is_not_sent(rig: Rig) -> None:
    """Speed before path: without the path follower's answer to the speed, the path never goes out (it would be
    flown at whatever speed the DSP had) and the ground station is told why; the started task ends failed."""
    paths: list[DatosSegCam] = []
    sub = rig.gcs.session.declare_subscriber(
        keys.slot_key(ROBOT, "ral", "path"),
        lambda s: paths.append(msgspec.msgpack.decode(s.payload.to_bytes(), type=DatosSegCam)),
    )
    rig.manager.answer_speed = False
    try:
        reply = rig.gcs.send(ROBOT, ten_waypoints())
        assert not reply.accepted and "did not acknowledge speed 4 m/s" in reply.reason, reply
        ended = rig.manager.end_tasks()[-1]
        assert ended.status == "failed" and ended.task_id == reply.task_id and "acknowledge" in ended.detail
        rig.manager.answer_speed = True
        again = rig.gcs.send(ROBOT, ten_waypoints())
        assert again.accepted, again.reason
        wait_until(lambda: len(paths) == 1, what="the answered task's path on ral/path")
        assert len(paths) == 1, "the unanswered task's path was never published"
    finally:
        sub.undeclare()


def test_pan_tilt_angles_are_sent_again_while_the_telemetry_shows_the_gimbal_elsewhere(rig: Rig) -> None:
    """DATOS is best effort: a lost datum must not leave the gimbal away while the station is told the task runs; once
    the gimbal was seen there, another source moving it is not fought."""
    from bbcs.contracts.pan_tilt import DatosPT
    from ral.tasks import PT_RESEND_S

    sent: list[DatosPT] = []
    withdrawn: list[zenoh.Sample] = []
    sub = rig.gcs.session.declare_subscriber(
        keys.slot_key(ROBOT, "ral", "pt_datos"),
        lambda s: withdrawn.append(s) if s.kind == zenoh.SampleKind.DELETE else sent.append(
            msgspec.msgpack.decode(s.payload.to_bytes(), type=DatosPT)),
    )
    try:
        reply = rig.gcs.send(ROBOT, gri.SetPanTilt(pan=33.0, tilt=-21.0))
        assert reply.accepted, reply.reason
        wait_until(lambda: len(sent) == 1, what="the angles on ral/pt_datos")
        stamp = itertools.count(100)

        def gimbal_at(pan: float, tilt: float) -> None:
            rig.manager.telemetry(RobotTelemetry(stamp=float(next(stamp)), pan_deg=pan, tilt_deg=tilt))

        gimbal_at(0.0, 0.0)  # the first datum was lost: the gimbal did not move
        assert len(sent) == 1, "not at once: the gimbal is given time to get there"

        def resent() -> bool:
            gimbal_at(0.0, 0.0)
            return len(sent) >= 2

        wait_until(resent, 3 * PT_RESEND_S + 10, "the angles sent again")
        assert sent[1].ref_pan == 33.0 and sent[1].ref_tilt == -21.0
        assert rig.ral.pt_resends >= 1
        gimbal_at(33.2, -21.1)  # there now: checked once, the RAL stops watching
        count = len(sent)
        wait_until(lambda: not rig.ral._pt_sent, 10, "the angles seen reached")
        deadline = rig.ral.clock() + PT_RESEND_S + 1.0
        while rig.ral.clock() < deadline:  # an absence is checked over a time: telemetry at 10 Hz through it
            gimbal_at(0.0, 0.0)  # vision (or a swapped route) moves the gimbal away: not fought
            time.sleep(0.1)
        assert len(sent) == count, "once the angles were reached, nothing more is sent"

        # campaign seed 41: the angles the RAL put on its slot belong to the task; once it has ended they are
        # withdrawn, so an input routed back to the slot (or a pan & tilt restarted later) reads no datum
        assert withdrawn == []
        reply = rig.gcs.send(ROBOT, gri.Cancel(task_type="pan_tilt"))
        assert reply.accepted, reply.reason
        wait_until(lambda: rig.manager.telemetry() or bool(withdrawn), 10, "ral/pt_datos withdrawn")
        assert len(sent) == count
    finally:
        sub.undeclare()


@pytest.fixture
def handler_threads(monkeypatch: pytest.MonkeyPatch) -> dict[str, set[str]]:
    """The threads (by name) that ran each of the RAL's bus handlers; patched before the RAL starts (``rig``)."""
    seen: dict[str, set[str]] = {}
    for name in ("_on_manager_state", "_on_gcs_token", "_on_gcs_heartbeat", "_on_speed_ack"):
        def spy(self: Ral, sample: object, original=getattr(Ral, name), name: str = name) -> None:
            seen.setdefault(name, set()).add(threading.current_thread().name)
            original(self, sample)
        monkeypatch.setattr(Ral, name, spy)
    return seen


def test_the_rals_bus_inputs_are_handled_on_its_event_loop(handler_threads: dict[str, set[str]], rig: Rig) -> None:
    """The manager's state, a station's token and heartbeats and the path follower's speed acknowledgement are
    handled on the RAL's one event loop, as any module's inputs (in order with its ticks, counted in a lockstep
    step), never on Zenoh's threads; the task itself still runs (its admission waits on the acknowledgement on
    the worker thread while the loop takes the acknowledgement in)."""
    link = Gcs(local_client(rig.port), name="pilot", link=[ROBOT])  # a linking station: token and heartbeats
    try:
        wait_until(lambda: "link_up" in rig.kinds(), what="link_up")
        reply = rig.gcs.send(ROBOT, ten_waypoints())  # answered after the speed acknowledgement came in
        assert reply.accepted, reply.reason
        rig.manager.telemetry(RobotTelemetry(stamp=1.0, position=GeoPoint(lat=37.41, lon=-6.0, alt=30.0)))
    finally:
        link.close()
    wait_until(lambda: "link_lost" in rig.kinds(), what="link_lost (the token gone)")
    wanted = {"_on_manager_state", "_on_gcs_token", "_on_gcs_heartbeat", "_on_speed_ack"}
    wait_until(lambda: wanted <= set(handler_threads), 10, "every handler called")
    loop = rig.ral._loop_thread
    assert loop is not None
    assert dict(handler_threads) == {name: {loop.name} for name in wanted}
