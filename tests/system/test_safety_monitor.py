"""The flight-safety monitor on the shipped ``bbcs_conf/uav1_sim.toml`` as the oracle of a flight: take-off, goto,
land and 20 s of watching show no breach; then a DSP command that a test identity puts straight on the pan & tilt's
command key, with no task behind it, reaches the DSP and is reported, with its evidence."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from monitor_support import attach_monitor, free_udp_port, send_truth_to  # noqa: E402
from test_gcs_mission import ROBOT, SimRobot, connect, grid_path, launch_robot  # noqa: E402

from bbcs import keys
from bbcs.contracts import dsp as p
from bbcs.contracts import gri
from bbcs.contracts.safety import Invariant, Severity
from bbcs.lockstep import SimSettings, settings_env
from bbcs.session import local_client, open_session
from bbcs.slots import Kind, OutputSlot, Publisher
from bbcs.testing import wait_until

WATCH_AFTER_S = 20.0
"""Simulated seconds watched after the last task ends: nothing unrequested may follow."""


@pytest.mark.timeout(240)  # a whole robot launched and flown: 60-110 s at a load of 40-50 on 2 cores
def test_monitor_sees_a_clean_flight_and_reports_a_command_with_no_task(tmp_path: Path) -> None:
    truth = free_udp_port()
    la, record = launch_robot(tmp_path, lockstep=True, edit=send_truth_to(truth))
    gcs = None
    try:
        # a lockstep member (as in the campaign): the simulation steps only once the monitor has judged the last step
        sim = SimSettings(robot=ROBOT, connect=[f"tcp/127.0.0.1:{la.port}"], speed="max")
        with attach_monitor(la.port, tmp_path, truth_port=truth, env=settings_env(sim)) as monitor:
            gcs = connect(la.port, "ground1")
            robot = SimRobot(la, gcs, record)
            monitor.wait_watching()

            # take-off, a goto 20 m above home two grid cells north, land: each to completion
            up = robot.ensure_airborne()
            assert up.home is not None and up.position is not None
            goal = grid_path(up.position, steps=[(2, 0)])[0]
            goal = gri.Waypoint(lat=goal.lat, lon=goal.lon, alt=up.home.alt + 20.0)
            for task in (gri.Goto(waypoints=[goal], speed=5.0), gri.Land()):
                start = len(robot.events)
                reply = gcs.send(ROBOT, task)
                assert reply.accepted, reply.reason
                done = robot.wait_event(lambda e, r=reply: e.task_id == r.task_id and e.kind != "task_accepted",
                                        90, f"{type(task).__name__} ended", after=start)
                assert done.kind == "task_completed", done
            landed = robot.wait_state(lambda s: s.airborne is False, 15, "on the ground")
            robot.wait_state(lambda s: s.stamp >= landed.stamp + WATCH_AFTER_S, 60,
                             f"{WATCH_AFTER_S:g} simulated seconds on the ground")
            flight = monitor.settle()
            assert flight.verdicts >= 3 and flight.truth > 100 and flight.commands > 5 and flight.gri_compared > 5, \
                flight
            flight_breaches = monitor.seen()

            # a command with nothing behind it, straight on a DSP command key by a test identity
            n_sent = len(robot.commands())
            s = open_session(local_client(la.port))
            try:
                pub = Publisher(s, keys.slot_key(ROBOT, p.MODULE, p.commands_slot("pan_tilt")),
                                OutputSlot("commands", p.DspCommands, kind=Kind.STREAM))
                pub.publish(p.DspCommands(sender="intruder", commands=[p.SetPanTiltAngles(pan_deg=33.0,
                                                                                           tilt_deg=-11.0)]))
                wait_until(lambda: "SET_PT_ANGLES" in [c["name"] for c in robot.commands()[n_sent:]], 15,
                           "the injected command at the DSP")
                injected = monitor.wait_breach(lambda b: "SetPanTiltAngles" in b.summary, 15,
                                               "the injected command reported")
                pub.close()
            finally:
                s.close()
            assert (injected.invariant, injected.kind, injected.severity) == (
                Invariant.COMMAND_TRACED, "untraced_command", Severity.ERROR)  # it moves the gimbal
            assert "pan_deg=33.0" in injected.evidence[0] and "'pan_tilt'" in injected.evidence[0]
            assert any(line.startswith("tasks running then: none") for line in injected.evidence), injected

            monitor.assert_no_breaches(flight_breaches)
    finally:
        if gcs is not None:
            gcs.close()
        la.stop()
        la.cleanup()
