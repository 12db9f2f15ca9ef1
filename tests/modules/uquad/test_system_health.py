"""Issue 30 case 4 by effect: a loss of control on the shipped uquad1_sim.toml is reported by the robot itself.

``cromat launch`` of the shipped manifest and .conf in lockstep (``[sim] lockstep = true``, ``--speed max``: the
simulator steps on the bus barrier and every bus process reads simulated time, docs/uquad.md §1.1; the robot's
processes at a flight computer's priority, logs in the test's folder: nothing else changed), a ground station takes
off to 3 m and sends a goto; on the way a motor is lost through the simulator's fault-injection port. Checked, in
simulated time (the flight is the same at any machine load): the GRI carries the loss-of-control error (604, with
its severity) within 1 s of the simulator's truth first showing the quadrotor tilted past 45°; the goto failed
with the reason; the failsafe ran (truth: the motors cut, on the ground); and for 20 s after, nothing moves it.
"""

from __future__ import annotations

import json
import math
import socket
import sys
from pathlib import Path

import pytest

from bbcs.contracts import gri
from bbcs.contracts.error_codes import RalErrorCode, UquadErrorCode
from bbcs.contracts.safety import Severity
from bbcs.testing import wait_until
from modules.uquad.config import load_config
from modules.uquad.geo import Home
from ral.gcs.api import Gcs, session_config

from .lockstep_flight import MANIFEST, SPEED, Truth, lockstep_manifest, sim_ports

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "module_manager"))
from launch_support import Launch  # noqa: E402

ROBOT = "uquad1"
HEIGHT_M = 3.0
LOSS_TILT_DEG = 45.0
"""The truth shows a loss of control once the quadrotor is tilted past this (the .conf's HEALTH max_tilt_deg)."""
WATCH_S = 20.0
"""Simulated seconds watched after the failsafe: nothing may move the quadrotor."""


def tilt_deg(doc: dict) -> float:
    roll, pitch = doc["x"][3], doc["x"][4]
    return math.degrees(math.acos(max(-1.0, min(1.0, math.cos(roll) * math.cos(pitch)))))


@pytest.mark.timeout(300)
def test_a_lost_motor_is_reported_within_1s_the_task_failed_and_the_motors_cut(tmp_path):
    launch = Launch(lockstep_manifest(tmp_path), tmp_path, *SPEED)
    gcs = truth = control = None
    try:
        launch.wait_line("modules up in", 120)
        ports = sim_ports(tmp_path / "logs")
        truth = Truth(ports["truth"])
        control = socket.create_connection(("127.0.0.1", ports["control"]), timeout=10)
        gcs = Gcs(session_config([f"tcp/127.0.0.1:{launch.port}"]), timeout_s=10.0)
        events: list[gri.GriEvent] = []
        gcs.events(ROBOT, events.append)
        states: list[gri.GriState] = []
        gcs.watch(ROBOT, states.append)

        def state() -> gri.GriState:
            return states[-1]

        truth.wait(lambda: states and state().position is not None and state().airborne is False, 60,
                   "calibrated uquad telemetry in the GRI state")
        home = state().position
        take_off = gcs.send(ROBOT, gri.TakeOff(height=HEIGHT_M))
        assert take_off.accepted, take_off.reason
        truth.wait(lambda: any(e.kind == "task_completed" and e.task_id == take_off.task_id for e in events), 60,
                   "take-off completed")

        cfg = load_config(MANIFEST.parent / "uquad1.conf")
        local = Home(cfg.home_lat, cfg.home_lon, cfg.home_alt)  # the simulator's (truth's) origin
        lat, lon, _ = local.to_geo(8.0, 0.0, HEIGHT_M)
        goto = gcs.send(ROBOT, gri.Goto(waypoints=[gri.Waypoint(lat=lat, lon=lon, alt=home.alt + HEIGHT_M)]))
        assert goto.accepted, goto.reason
        truth.wait(lambda: truth.last["x"][0] > 1.0, 20, "flying toward the waypoint")
        assert not any(e.code in (RalErrorCode.LOSS_OF_CONTROL, UquadErrorCode.LOSS_OF_CONTROL)
                       for e in state().errors), "no loss of control before the fault"

        control.sendall(b'{"motor": 1, "efficiency": 0.0}\n')
        answer = json.loads(control.makefile("rb").readline())
        assert answer["ok"] is True, answer
        injected = truth.epoch + answer["t"]  # the fault's simulated time, as the robot's clocks read it

        def truth_loss() -> float | None:
            return next((doc["stamp"] for doc in list(truth.lines)
                         if doc["stamp"] >= injected and tilt_deg(doc) > LOSS_TILT_DEG), None)

        truth.wait(lambda: truth_loss() is not None, 10, "the truth showing the quadrotor tilted past 45°")
        lost_at = truth_loss()
        assert lost_at is not None

        def reported(code: int, module: str) -> float | None:
            """The simulated time the GRI first showed ``code`` from ``module`` (its state's stamp)."""
            return next((s.stamp for s in list(states) if s.stamp >= injected and any(
                e.code == code and e.module == module for e in s.errors)), None)

        try:
            truth.wait(lambda: reported(RalErrorCode.LOSS_OF_CONTROL, "ral") is not None, 10,
                       "the loss of control (604) in the GRI state")
        except AssertionError as exc:  # once in a clean-clone run under the suite's load: what the robot said
            logs = tmp_path / "logs"
            tails = {name: (logs / f"{name}.log").read_text(errors="replace").splitlines()[-15:]
                     for name in ("ral", "uquad") if (logs / f"{name}.log").exists()}
            raise AssertionError(f"{exc}\nlost at {lost_at:.2f}; last GRI state {state().stamp:.2f}: errors "
                                 f"{state().errors}, airborne {state().airborne}; events {events[-6:]}; "
                                 f"logs {tails}") from None
        ral_at = reported(RalErrorCode.LOSS_OF_CONTROL, "ral")
        assert ral_at is not None
        # the RAL's own record, graded; the manager's record of the same code (the RAL's error slot) comes bare, and
        # in lockstep it sorts first: the manager stamps its error records on the wall clock, behind simulated time
        graded = [e for e in state().errors if e.code == RalErrorCode.LOSS_OF_CONTROL and e.severity is not None]
        assert graded, state().errors
        error = graded[0]
        assert error.severity == Severity.CRITICAL and "loss of control" in error.detail, error
        assert error.stamp <= ral_at, (error.stamp, ral_at)  # the RAL decided it no later than the GRI showed it
        assert ral_at - lost_at < 1.0, f"reported {ral_at - lost_at:.2f} simulated s after the truth showed it"

        truth.wait(lambda: any(e.kind == "task_failed" and e.task_id == goto.task_id for e in events), 10,
                   "the goto failed")
        failed = next(e for e in events if e.kind == "task_failed" and e.task_id == goto.task_id)
        assert "loss of control" in failed.detail or "LOSS_OF_CONTROL" in failed.detail, failed.detail
        # the uQuad's failsafe: tumbling, the flight module cuts its motors itself (error 706 on the GRI); had it
        # not tumbled, the RAL would have landed it (a failsafe event)
        truth.wait(lambda: reported(UquadErrorCode.LOSS_OF_CONTROL, "uquad") is not None
                   or any(e.kind == "failsafe" for e in events), 10, "the failsafe on the GRI")
        truth.wait(lambda: truth.last["on_ground"] and max(truth.last["w"]) == 0.0, 20,
                   "the failsafe's effect: motors stopped, on the ground")
        cut = reported(UquadErrorCode.LOSS_OF_CONTROL, "uquad")
        truth.wait(lambda: state().airborne is False, 10, "the GRI showing it on the ground")

        # 20 simulated seconds more: nothing moves it (no motor set-point, no task left running that could)
        mark = len(truth.lines)
        watched_from = truth.lines[mark - 1]["t"]
        truth.wait(lambda: truth.last["t"] - watched_from >= WATCH_S, WATCH_S + 1.0,
                   f"{WATCH_S:g} simulated s of truth after the failsafe")
        after = truth.lines[mark:]
        assert len(after) > 200, "the truth stream went on"
        assert all(max(doc["w"]) == 0.0 and max(doc["esc"]) == 0.0 and doc["on_ground"] for doc in after), (
            "something drove the motors after the failsafe")
        wait_until(lambda: state().stamp >= truth.epoch + watched_from + WATCH_S, 30,
                   "the GRI state at the end of the watch")
        assert state().airborne is False and not any(t.task_type == "movement" and t.kind not in ("land", "hold")
                                                     for t in state().tasks), state().tasks
        print(f"truth tilt > {LOSS_TILT_DEG:g}° at +{lost_at - injected:.2f} simulated s after the fault; on the "
              f"GRI: 604 {ral_at - lost_at:.2f} s later (decided at {error.stamp - lost_at:+.2f} s), 706 (motors "
              f"cut) {'-' if cut is None else f'{cut - lost_at:.2f} s'}; "
              f"events {[(e.kind, e.detail) for e in events]}")
    finally:
        for closeable in (gcs, truth, control):
            if closeable is not None:
                closeable.close()
        launch.stop()
        launch.cleanup()
    sim_log = (tmp_path / "logs" / "uquad_sim.log").read_text()
    assert "goes on" not in sim_log, sim_log[-3000:]  # no step went on without a member or with a link unsettled
    print(sim_log.strip().splitlines()[-1])
