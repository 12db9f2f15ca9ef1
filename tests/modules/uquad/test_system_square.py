"""End to end: ``cromat launch`` of uquad1_sim.toml (router, quadrotor simulator, motor driver, flight module,
three loggers, the RAL — the real Module Manager) in lockstep (``[sim] lockstep = true``, ``--speed max``: the
simulator steps on the bus barrier, every bus process reads simulated time, and the deadlines below are simulated
seconds, docs/uquad.md §1.1) and a ground station on the GCS API: take off, fly a 4-waypoint square, land.
Checked by effect: the simulator's true state (its truth port) follows the square and ends on the ground with the
motors stopped; the ground station is told each task completed; the loggers wrote.
The take-off height is the ground station's (not the .conf's default of 3 m), and the seed's manual mode moves
the hover point from the ground station with every ESC set-point in [MOTOR_MIN, MOTOR_MAX]; a manual step that
would leave the allowed heights is refused with the reason and moves nothing.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from bbcs.contracts import gri
from bbcs.testing import wait_until
from modules.uquad.config import load_config
from modules.uquad.geo import Home
from ral.gcs.api import Gcs, session_config

from .lockstep_flight import MANIFEST, SPEED, Truth, lockstep_manifest, sim_ports

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "module_manager"))
from launch_support import Launch  # noqa: E402

ROBOT = "uquad1"
SIDE_M = 4.0
FAILSAFE_S = 2.0
"""The link-loss failsafe (land) after this long without the pilot's ground station (the RAL judges the ground
station's link on the wall clock: a ground station is outside the simulation)."""
HEIGHT_M = 4.5
"""Not the .conf's TAKEOFF_HEIGHT_DEFAULT (3 m): the ground station's height must reach the quad."""
TAKE_OFF_DONE_M = 0.6 + 0.3
"""A take-off completes once the robot's own estimate is within the manifest's altitude_tolerance_m (0.6 m) of its
height; the truth may lie a little further, by the estimator's error (a clean-clone run: 1.399 m for 2 m)."""


def manifest(tmp_path: Path) -> Path:
    """The shipped uquad1_sim.toml as it is (its flight processes at a flight computer's priority where the OS allows
    it, the .conf's motor timeouts), in lockstep, with the loggers writing into tmp_path and a short link-loss
    failsafe."""

    def short_failsafe(text: str) -> str:
        assert 'failsafe_timeout_s = "10"' in text
        return text.replace('failsafe_timeout_s = "10"', f'failsafe_timeout_s = "{FAILSAFE_S:g}"')

    return lockstep_manifest(tmp_path, short_failsafe)


@pytest.mark.timeout(300)
def test_take_off_square_land_from_the_ground_station(tmp_path):
    launch = Launch(manifest(tmp_path), tmp_path, *SPEED)
    gcs = truth = pilot = None
    try:
        launch.wait_line("modules up in", 120)
        truth = Truth(sim_ports(tmp_path / "logs")["truth"])
        gcs = Gcs(session_config([f"tcp/127.0.0.1:{launch.port}"]), timeout_s=10.0)
        pilot = Gcs(session_config([f"tcp/127.0.0.1:{launch.port}"]), name="pilot", link=[ROBOT])
        events: list[gri.GriEvent] = []
        gcs.events(ROBOT, events.append)
        states: list[gri.GriState] = []
        gcs.watch(ROBOT, states.append)

        def completed(reply: gri.TaskReply, what: str, sim_s: float) -> None:
            """The task completed, and the truth read up to that instant: the event and the truth stream have no
            order between them (the second take-off's truth was once read from before it, on the ground)."""
            assert reply.accepted, reply.reason

            def done() -> gri.GriEvent | None:
                return next((e for e in events if e.kind == "task_completed" and e.task_id == reply.task_id), None)

            truth.wait(lambda: done() is not None, sim_s, what)
            stamp = done().stamp  # type: ignore[union-attr]
            truth.wait(lambda: truth.last.get("stamp", float("inf")) >= stamp, 5, f"the truth up to: {what}")

        truth.wait(lambda: states and states[-1].position is not None and states[-1].kind == "uquad", 60,
                   "calibrated uquad telemetry in the GRI state")
        home = states[-1].position
        assert states[-1].airborne is False
        completed(gcs.send(ROBOT, gri.TakeOff(height=HEIGHT_M)), "take-off completed", 60)
        assert truth.last["x"][2] > HEIGHT_M - TAKE_OFF_DONE_M and not truth.last["on_ground"], (
            truth.last, states[-1].telemetry)

        cfg = load_config(MANIFEST.parent / "uquad1.conf")
        local = Home(cfg.home_lat, cfg.home_lon, cfg.home_alt)  # the simulator's (truth's) origin
        corners = [(SIDE_M, 0.0), (SIDE_M, SIDE_M), (0.0, SIDE_M), (0.0, 0.0)]
        waypoints = []
        for e, n in corners:
            lat, lon, _ = local.to_geo(e, n, HEIGHT_M)
            waypoints.append(gri.Waypoint(lat=lat, lon=lon, alt=home.alt + HEIGHT_M))
        start = len(truth.lines)
        completed(gcs.send(ROBOT, gri.Goto(waypoints=waypoints)), "square completed", 120)
        flown = np.array([line["x"][:3] for line in truth.lines[start:]])
        for e, n in corners:  # the aircraft itself passed within a metre of every corner, at the right height
            d = np.hypot(flown[:, 0] - e, flown[:, 1] - n)
            assert d.min() < 1.0, (e, n, d.min())
            assert abs(flown[d.argmin(), 2] - HEIGHT_M) < 0.7

        # hold, then a goto interrupted by abort: the aircraft stops where it is, still flying
        assert gcs.send(ROBOT, gri.Hold()).accepted
        far = local.to_geo(SIDE_M * 3, 0.0, HEIGHT_M)
        reply = gcs.send(ROBOT, gri.Goto(waypoints=[gri.Waypoint(lat=far[0], lon=far[1], alt=home.alt + HEIGHT_M)]))
        assert reply.accepted, reply.reason
        try:
            truth.wait(lambda: truth.last["x"][0] > 1.0, 20, "moving toward the far waypoint")
        except AssertionError:
            print("TRUTH", truth.last, "STATE", states[-1].tasks, states[-1].errors[-4:],
                  "EVENTS", [(e.kind, e.task_id, e.detail) for e in events[-8:]])
            print("UQUAD LOG", (tmp_path / "logs" / "uquad.log").read_text()[-3000:])
            raise
        assert gcs.abort(ROBOT).accepted
        truth.wait(lambda: any(e.kind == "aborted" for e in events), 10, "the ground station told of the abort")
        truth.wait(lambda: np.linalg.norm(truth.last["x"][6:9]) < 0.3, 20, "stopped after the abort")
        stopped_at = truth.last["x"][0]
        assert stopped_at < SIDE_M * 3 - 2.0 and not truth.last["on_ground"], (
            stopped_at, truth.last, [(e.kind, e.detail) for e in events[-8:]],
            [(e.module, e.code, e.detail) for e in states[-1].errors[-4:]])

        # the seed's manual mode: steps of the hover point from the ground station. A step moves the hover set
        # point, so the quad is measured from where it settled on it, not while it still drifted onto it after the
        # abort (a clean-clone run took the point at 0.3 m/s and missed the step's point by more than 0.4 m)
        truth.wait(lambda: truth.settled(2.0, 0.1), 30, "settled on the abort's hold point")
        before = np.array(truth.last["x"][:3])
        mark = len(truth.lines)
        completed_manual = gcs.send(ROBOT, gri.Manual(north=1.5, up=1.0))
        assert completed_manual.accepted, completed_manual.reason
        truth.wait(lambda: np.linalg.norm(np.array(truth.last["x"][:3]) - before - [0.0, 1.5, 1.0]) < 0.4, 30,
                   "the quad at the manual step's point")
        truth.wait(lambda: np.linalg.norm(truth.last["x"][6:9]) < 0.3, 20, "settled after the manual step")
        esc = [w for line in truth.lines[mark:] for w in line["esc"]]
        assert esc and all(cfg.values.MOTOR_MIN <= w <= cfg.values.MOTOR_MAX for w in esc), (min(esc), max(esc))
        target = before + [0.0, 1.5, 1.0]
        refused = gcs.send(ROBOT, gri.Manual(up=-5.0))  # to 0.5 m: under MIN_CLEARANCE (1 m)
        assert not refused.accepted and "below" in refused.reason, refused.reason
        assert states[-1].tasks and all(x.kind == "manual" for x in states[-1].tasks if x.task_type == "movement")
        mark = len(truth.lines)
        truth.wait(lambda: len(truth.lines) > mark + 40, 3, "two more seconds of truth")
        # had it been taken, the set point would have gone 2 m down in those 2 s (CRUISE_SPEED): it held, within
        # the estimator's error (the square's RMS is about 0.4 m)
        held = np.array(truth.last["x"][:3])
        assert np.linalg.norm(held - target) < 1.0 and held[2] > target[2] - 0.5, ("a refused step moved it", held)

        completed(gcs.send(ROBOT, gri.Land()), "landing completed", 60)
        try:
            truth.wait(lambda: truth.last["on_ground"] and max(truth.last["w"]) == 0.0, 10,
                       "on the ground, motors stopped")
        except AssertionError:
            print("TRUTH", truth.last, states[-1])
            raise
        assert states[-1].kind == "uquad"
        assert truth.last["esc_frames"] > 1000  # the driver commanded the ESCs continuously

        # the link-loss failsafe of the same RAL lands the quad: the pilot's ground station goes away in flight
        wait_until(lambda: states[-1].link == "up", 10, "the pilot's link up")
        completed(gcs.send(ROBOT, gri.TakeOff(height=2.0)), "second take-off completed", 60)
        assert truth.last["x"][2] > 2.0 - TAKE_OFF_DONE_M and not truth.last["on_ground"]
        start = len(events)
        pilot.close()
        pilot = None
        # the link's loss is judged on the wall clock (FAILSAFE_S: the ground station is outside the simulation),
        # the landing that follows in simulated time
        wait_until(lambda: any(e.kind == "failsafe" for e in events[start:]), 20, "the failsafe at the ground station")
        truth.wait(lambda: truth.last["on_ground"] and max(truth.last["w"]) == 0.0, 60,
                   "landed by the failsafe, motors stopped")
    finally:
        if gcs is not None:
            gcs.close()
        if pilot is not None:
            pilot.close()
        if truth is not None:
            truth.close()
        launch.stop()
        launch.cleanup()
    for kind in ("imu_raw", "state", "control"):  # one logging process per data type wrote its file
        lines = (tmp_path / f"{ROBOT}_{kind}.jsonl").read_text().splitlines()
        assert len(lines) > 100, kind
    sim_log = (tmp_path / "logs" / "uquad_sim.log").read_text()
    assert "goes on" not in sim_log, sim_log[-3000:]  # no step went on without a member or with a link unsettled
    print(sim_log.strip().splitlines()[-1])
