"""The lidar survey UAV in lockstep logs the same scans and poses on a quiet machine and beside 2 busy processes.

``bbcs_conf/uav1_lidar_sim.toml`` launched with ``[sim] lockstep = true`` at ``--speed max`` (``cromat launch``):
the MTi-G/LD-MRS simulators are a member of the barrier and the logger's device links are paired in it
(docs/simulation.md, "The barrier"; docs/lidar_logger.md §8). The ground station is outside any simulation: its
requests reach the robot at whatever simulated time its wall clock allows, so here the test's station is a lockstep
member too (``Station``): it sends each task at a step boundary, at a set simulated time (the take-off at 4 s, the
survey at 20 s, the take-off having ended by then) and holds the simulation once it has what it compares. Not on the
task's end event: the robot's judging of a task's end is exact to one frame (the RAL judges every telemetry sample,
but a sample and the step's time reach it in either order: a take-off ended at 14.8 s in one run and 15.0 s in
another), and a task sent on it would start the rest of the flight a step apart. (Before the RAL judged each sample
as it came, its tick judged the newest, and a survey once ended two frames apart.) Asserted: the same task events
(their simulated times within one step); the same DSP record, times included (the same flight: the DSP simulator's
physics is a function of the commands and their times); and the same logged scans up to the survey's end: count, end
times, attached poses, every point.
"""

from __future__ import annotations

import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from bbcs import SessionConfig, open_session
from bbcs.contracts import gri
from bbcs.contracts import tasks as t
from bbcs.lockstep import Ask, Member
from bbcs.testing import wait_until

SYSTEM = Path(__file__).resolve().parents[2] / "system"
sys.path.insert(0, str(SYSTEM))
sys.path.insert(0, str(SYSTEM.parent / "module_manager"))
from launch_support import Launch  # noqa: E402
from lockstep_support import busy_processes, stop, survey_manifest  # noqa: E402
from test_gcs_mission import ROBOT, SimRobot, connect  # noqa: E402

from modules.dsp.sim.record import read_record  # noqa: E402
from modules.lidar_logger.logformats import load_log  # noqa: E402
from modules.lidar_logger.sim import SEED_UTC_START  # noqa: E402

TAKE_OFF_T = 4.0
"""Simulated second of the take-off: the station paces the simulation to twice real time until its link is up."""
SURVEY_T = 20.0
"""Simulated second of the survey (the take-off to 10 m ends at about 15 s)."""
HOME = (37.4117, -6.0025)
"""The DSP simulator's default home."""
AREA = ((0.0002, 0.0001), (0.0002, 0.0007), (0.0008, 0.0007), (0.0008, 0.0001))
"""About 55 m (east) x 67 m (north), north-east of home: two sweep lines at 30 m (tests/system/test_survey_dtm.py's;
the shipped 71 x 89 m area takes twice as long)."""
STEP_EPS_S = 1e-6
"""Simulated seconds are sums of 0.02-s physics steps: 20 s is 19.99999999999966 or 20.00000000000001."""
TAIL_S = 2.0
"""Simulated seconds the station lets run after the landing before it holds the simulation."""


class Station:
    """The test's ground station as a member of the robot's barrier (test only: a real one is outside)."""

    def __init__(self, port: int) -> None:
        self.session = open_session(SessionConfig(mode="client", connect=[f"tcp/127.0.0.1:{port}"]))
        self._cond = threading.Condition()
        self._ask: Ask | None = None
        self.member = Member(self.session, ROBOT, "station", self._on_ask)

    def _on_ask(self, ask: Ask) -> None:
        with self._cond:
            self._ask = ask
            self._cond.notify_all()

    def next_ask(self, timeout_s: float) -> Ask:
        with self._cond:
            assert self._cond.wait_for(lambda: self._ask is not None, timeout_s), "no lockstep ask"
            ask, self._ask = self._ask, None
            assert ask is not None
            return ask

    def close(self) -> None:
        self.member.close()
        self.session.close()


@dataclass
class Directed:
    record: list[tuple[float, str, str]]
    events: list[tuple[str, str, float]]
    end_t: float
    """Simulated second the station held the simulation at."""
    scans: dict[str, np.ndarray]
    sim_s: float
    wall_s: float


def router_up(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return True
    except OSError:
        return False


def fly(tmp_path: Path, tasks: list[tuple[float, object]], timeout_s: float = 240.0) -> Directed:
    """Launch, then send each ``(simulated second, task)`` at the first step at or after its second (the task
    before it ended), hold the simulation ``TAIL_S`` after the last one ended, stop the launch, read the logs."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    manifest, record = survey_manifest(tmp_path)
    la = Launch(manifest, tmp_path, "--speed", "max")
    station = gcs = None
    try:
        wait_until(lambda: router_up(la.port), 60, "the robot's router")
        station = Station(la.port)  # before any module is up: the simulation is at 0 until the manager lets go
        la.wait_line("modules up", 150)
        gcs = connect(la.port, "surveyor")
        robot = SimRobot(la, gcs, record)
        deadline = time.monotonic() + timeout_s
        linked, todo, pending, events = False, sorted(tasks, key=lambda at_task: at_task[0]), None, []
        wall0 = t0 = end_t = None
        first = station.next_ask(60)
        assert first.now.t == 0, f"the station joined at simulated {first.now.t} s"
        ask = first
        while True:
            assert time.monotonic() < deadline, f"the flight took over {timeout_s} s: {events}"
            now = ask.now.t
            if end_t is not None and now >= end_t:
                station.member.answer(ask, activity=0, busy="the test has its flight")  # held from here on
                end_t = now
                break
            with robot.lock:
                states, seen = list(robot.states), list(robot.events)
            if not linked:  # the link comes up on the wall clock: the simulation waits at twice real time for it
                linked = bool(states) and states[-1].link == "up" and "survey" in states[-1].available
                assert linked or now < TAKE_OFF_T, "the station's link was not up by the take-off"
                if not linked:
                    time.sleep(0.1)
            if pending is not None:
                ended = [e for e in seen if e.task_id == pending and e.kind in ("task_completed", "task_failed")]
                if ended:  # stamps are epoch + simulated seconds: the epoch taken back out, to the millisecond
                    events.append((type(todo[0][1]).__name__, ended[0].kind,
                                   round(ended[0].stamp - first.now.epoch, 3)))
                    assert ended[0].kind == "task_completed", ended[0]
                    todo.pop(0)
                    pending = None
                    if not todo:
                        end_t = now + TAIL_S
            if linked and pending is None and todo and now >= todo[0][0] - STEP_EPS_S:  # steps are sums of 0.02
                assert now < todo[0][0] + 0.2 - STEP_EPS_S, f"{todo[0]} could not start in time (the last one ran on)"
                if wall0 is None:
                    wall0, t0 = time.monotonic(), now
                reply = gcs.send(ROBOT, todo[0][1])  # in this step, before the station answers it
                assert reply.accepted, reply.reason
                pending = reply.task_id
            with robot.lock:
                activity = robot.received + len(robot.events)
            station.member.answer(ask, activity=activity)
            ask = station.next_ask(60)
        assert wall0 is not None and t0 is not None
        wall_s = time.monotonic() - wall0
        la.stop()  # the logger stops the scanner and closes its files; simulated time stands at end_t
        log = load_log(next((tmp_path / "lidar").glob("Scan_*")))
        cut = log.end_time - SEED_UTC_START <= end_t - 1.0  # every scan of a step the barrier handled
        scans = {"end_time": log.end_time[cut], "pose_time": log.pose_time[cut], "lla": log.lla[cut],
                 "euler": log.euler[cut], "n_points": log.n_points[cut],
                 "first_point": log.first_point[cut], "xyz": log.xyz}
        return Directed(record=[(r["t"], r["name"], str(r["fields"])) for r in read_record(record)],
                        events=events, end_t=end_t, scans=scans, sim_s=end_t - t0, wall_s=wall_s)
    finally:
        if gcs is not None:
            gcs.close()
        if station is not None:
            station.close()
        la.stop()
        la.cleanup()


@pytest.mark.timeout(300)
def test_the_lidar_survey_in_lockstep_logs_the_same_scans_quiet_and_beside_busy_processes(tmp_path: Path) -> None:
    area = [t.Vertex(lat=HOME[0] + dlat, lon=HOME[1] + dlon) for dlat, dlon in AREA]
    tasks = [(TAKE_OFF_T, gri.TakeOff(height=10.0)),
             (SURVEY_T, t.Survey(polygon=area, height=30.0, overlap=0.3))]  # no landing: 40 s less
    quiet = fly(tmp_path / "quiet", tasks)
    busy = busy_processes(2)  # and the other test worker beside them: both processors oversubscribed
    try:
        loaded = fly(tmp_path / "loaded", tasks)
    finally:
        stop(busy)
    span = same_flight_until(quiet.record, loaded.record)
    print({"quiet": (round(quiet.sim_s, 1), round(quiet.wall_s, 1)), "loaded": (round(loaded.sim_s, 1),
           round(loaded.wall_s, 1)), "events": (quiet.events, loaded.events), "same_flight_until": span})
    assert [k for _, k, _ in quiet.events] == ["task_completed"] * 2
    assert [e[:2] for e in quiet.events] == [e[:2] for e in loaded.events]
    for (_, _, a), (_, _, b) in zip(quiet.events, loaded.events, strict=True):
        # the flight is the same (the DSP records, below); the RAL's completion *event* came two frames apart once
        # (ci35: 99.6 and 99.2 s, with equal records): exact to two frames, the cause open (simulation.md, Limits)
        assert abs(a - b) <= 2 * 0.2 + 1e-6, (quiet.events, loaded.events)
    assert quiet.record == loaded.record, span  # every command at the same simulated time: the same flight
    cut = min(span, quiet.end_t - 1.0, loaded.end_t - 1.0)
    a, b = (logged_until(d.scans, cut) for d in (quiet, loaded))
    n = len(a["end_time"])
    assert n >= 12.5 * (cut - 3.0) * 0.98, (n, cut)  # every rotation from the first valid pose (2 s) on
    for name, values in a.items():
        assert np.array_equal(values, b[name]), name


def same_flight_until(a: list[tuple[float, str, str]], b: list[tuple[float, str, str]]) -> float:
    """Simulated time of the first command the two DSP records differ in (time, name or fields): up to it the
    DSP simulator flew the same flight (its physics is a function of the commands and their times)."""
    for x, y in zip(a, b, strict=False):
        if x != y:
            return min(x[0], y[0])
    longer = a[len(b):] or b[len(a):]
    return longer[0][0] if longer else float("inf")


def logged_until(scans: dict[str, np.ndarray], cut: float) -> dict[str, np.ndarray]:
    """The logged scans that ended by simulated second ``cut``, and their points."""
    keep = scans["end_time"] - SEED_UTC_START <= cut
    n = int(keep.sum())
    points = int(scans["first_point"][n - 1] + scans["n_points"][n - 1]) if n else 0
    out = {k: v[keep] for k, v in scans.items() if k not in ("xyz", "first_point")}
    out["xyz"] = scans["xyz"][:points]
    return out
