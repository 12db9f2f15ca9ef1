"""A fleet in lockstep (``[sim] fleet``, docs/simulation.md): two robots launched from uav1_sim.toml at their own
homes, their routers meshed, on one barrier (paced, ``fleet_support.FLEET_PACE``): the first robot's DSP simulator
steps, the second's follows.

Tested by effect: both simulators read one clock (the same simulated time on both robots' ``@clock`` while the
fleet is held); the same task sent to both in one step reaches both DSPs at the same simulated time; a fleet task
is allocated by the robots among themselves over the mesh (the bids cross robots inside the barrier) and each DSP
receives its own target only; nothing reaches either DSP in the 20 simulated seconds after the landing; a follower
robot killed (its whole stack) leaves the leader flying on.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from bbcs.contracts import gri
from bbcs.contracts.fleet import FleetTarget, FleetTask
from bbcs.lockstep import current_time
from bbcs.session import local_client, open_session
from bbcs.testing import StepGate, wait_until
from module_manager.fleet import drop_sections
from ral.fleet_gcs import FleetView
from ral.gcs.api import Gcs, session_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "module_manager"))
from fleet_support import FLEET_PACE  # noqa: E402
from launch_support import Launch, group_members  # noqa: E402
from test_fleet_mesh import N_MODULES, VISION_SECTIONS, fleet_manifest  # noqa: E402

from modules.dsp.sim.record import read_record

FLEET = ["uav_a", "uav_b"]
HOMES = {"uav_a": (37.4117, -6.0025), "uav_b": (37.4117, -6.0000)}
"""About 220 m apart (as in test_fleet_alloc.py), at 12 m above sea level."""
HOME_ALT = 12.0
AFTER_S = 20.0
"""Simulated seconds watched after the landing: nothing unrequested may reach either DSP."""


def launch(tmp_path: Path, name: str, peers: list[int]) -> tuple[Launch, Path]:
    manifest, record = fleet_manifest(tmp_path, name, peers)
    text = drop_sections(manifest.read_text(), VISION_SECTIONS)
    old = '"--tcp", "127.0.0.1:{port:dsp}",'
    assert old in text, "uav1_sim.toml's DSP simulator command line changed"
    lat, lon = HOMES[name]
    text = text.replace(old, f'{old} "--home", "{lat},{lon},{HOME_ALT}",', 1)
    assert "\n[bus]\n" in text, "uav1_sim.toml has no [bus] table to put [sim] before"
    fleet = ", ".join(f'"{r}"' for r in FLEET)
    manifest.write_text(text.replace("\n[bus]\n", f"\n[sim]\nlockstep = true\nfleet = [{fleet}]\n\n[bus]\n", 1))
    return Launch(manifest, tmp_path / name, "--speed", f"{FLEET_PACE:g}"), record


class Station:
    """A ground station linked to both robots, keeping every event."""

    def __init__(self, port: int) -> None:
        self.gcs = Gcs(session_config([f"tcp/127.0.0.1:{port}"]), name="ground1", link=list(FLEET), timeout_s=10.0)
        self.lock = threading.Lock()
        self.events: list[gri.GriEvent] = []
        self.states: dict[str, gri.GriState] = {}
        for robot in FLEET:
            self.gcs.events(robot, self._on_event)
            self.gcs.watch(robot, self._on_state)

    def _on_event(self, event: gri.GriEvent) -> None:
        with self.lock:
            self.events.append(event)

    def _on_state(self, state: gri.GriState) -> None:
        with self.lock:
            self.states[state.robot] = state

    def completed(self, task_ids: dict[str, int]) -> bool:
        with self.lock:
            done = {(e.robot, e.task_id) for e in self.events if e.kind == "task_completed"}
        return all((robot, tid) in done for robot, tid in task_ids.items())

    def send_all(self, request: gri.TaskRequest) -> dict[str, int]:
        ids = {}
        for robot in FLEET:
            reply = self.gcs.send(robot, request)
            assert reply.accepted, f"{robot}: {reply.reason}"
            ids[robot] = reply.task_id
        return ids


def commands(record: Path) -> list[tuple[str, float, dict]]:
    return [(c["name"], c["t"], c["fields"]) for c in read_record(record)]


@pytest.fixture
def fleet(tmp_path: Path) -> Iterator[tuple[list[Launch], list[Path]]]:
    launches: list[Launch] = []
    try:
        a, record_a = launch(tmp_path, "uav_a", [])
        launches.append(a)
        b, record_b = launch(tmp_path, "uav_b", [a.port])
        launches.append(b)
        for la in launches:
            la.wait_line(f"all {N_MODULES} modules up", 90)
        yield launches, [record_a, record_b]
    finally:
        for la in reversed(launches):
            la.stop()
            la.cleanup()


@pytest.mark.timeout(300)  # two robots beside the other test workers: a loaded machine slows them
def test_a_fleet_in_lockstep_flies_on_one_clock_and_a_dead_follower_does_not_hold_the_leader(fleet) -> None:
    (a, b), records = fleet
    station = Station(a.port)
    session = open_session(local_client(a.port))
    gate = StepGate(session, "uav_a")
    try:
        gcs = station.gcs
        wait_until(lambda: gcs.robots(1.0) == FLEET, 30, "both robots in the station's robot list")
        wait_until(lambda: all(s.position is not None and s.manager_up and s.link == "up"
                               for s in dict(station.states).values()) and len(station.states) == 2,
                   60, "both robots' states with a position, the manager up and the station linked")

        def held(action: Callable[[], None], what: str, settle: Callable[[], bool]) -> None:
            """``action`` with the fleet held at one step, until ``settle`` (both DSPs got what it sent)."""
            with gate.closed():
                action()
                wait_until(settle, 30, what)

        # one clock: held, both robots' @clock say the same simulated time
        with gate.closed():
            wait_until(lambda: current_time(session, "uav_b") == current_time(session, "uav_a"), 10,
                       "the follower's clock at the leader's step")
            t_a, t_b = current_time(session, "uav_a"), current_time(session, "uav_b")
            assert t_a is not None and t_b is not None and t_a.t > 0 and t_a == t_b, (t_a, t_b)

        ids: dict[str, int] = {}
        held(lambda: ids.update(station.send_all(gri.TakeOff(height=10.0))), "both DSPs got the take-off",
             lambda: all(any(c[0] == "SET_MODE" for c in commands(r)) for r in records))
        wait_until(lambda: station.completed(ids), 90, "both take-offs completed")
        # after the start-up, without the pan & tilt's initial mode (lost or late: a start-up race, simulation.md)
        took_off = [[c for c in commands(r) if c[1] > 0.0 and c[0] != "SET_PT_MODE"] for r in records]
        assert took_off[0] == took_off[1] and took_off[0][-1][0] == "SET_MODE", \
            "the same take-off commands at the same simulated times on both"
        ids.clear()

        # a fleet task: one target by each robot's home, allocated by the robots over the mesh, each flown by its own
        view = FleetView(session)
        try:
            targets = {r[-1]: (round(lat + 2e-4, 4), round(lon + 2e-4, 4)) for r, (lat, lon) in HOMES.items()}
            n_before = [len(commands(r)) for r in records]
            view.post(FleetTask(id="t1", speed=8.0, targets=[
                FleetTarget(id=k, lat=lat, lon=lon, alt=HOME_ALT + 10.0) for k, (lat, lon) in targets.items()]))
            decision = view.wait(lambda: view.agreed("t1", set(FLEET)), 60)
            assert decision, view.decisions("t1")
            assert decision.routes == {"uav_a": ["a"], "uav_b": ["b"]}, decision.routes
            wait_until(lambda: view.visited("t1") == {"a", "b"}, 120, "both targets visited")
        finally:
            view.close()
        for robot, record, n in zip(FLEET, records, n_before, strict=True):
            flown = {(round(c[2]["lat"], 4), round(c[2]["lon"], 4)) for c in commands(record)[n:]
                     if c[0] == "ADD_WAYPOINT"}
            assert targets[robot[-1]] in flown, (robot, flown)
            other = next(k for k in targets if k != robot[-1])
            assert targets[other] not in flown, (robot, flown)
        n_before = [len(commands(r)) for r in records]
        held(lambda: ids.update(station.send_all(gri.Land())), "both DSPs got the landing",
             lambda: all(len(commands(r)) > n for r, n in zip(records, n_before, strict=True)))
        wait_until(lambda: station.completed(ids), 90, "both landings completed")

        # nothing unrequested in the 20 simulated seconds after the landing, on either robot
        landed = [commands(r) for r in records]
        end = current_time(session, "uav_a")
        assert end is not None
        wait_until(lambda: (now := current_time(session, "uav_a")) is not None and now.t >= end.t + AFTER_S, 60,
                   f"{AFTER_S:g} simulated seconds after the landing")
        assert [commands(r) for r in records] == landed, "a DSP received commands no task asked for"

        # the landing, sent to both in one step, reached both DSPs at the same simulated time
        modes = [[(c[1], c[2]["mode"]) for c in rec if c[0] == "SET_MODE"] for rec in landed]
        assert modes[0][-1] == modes[1][-1] and modes[0][-1][1] == 5, modes

        # the follower robot killed (its whole stack): the leader's simulation steps on without it
        for pid in group_members(b.pgid):
            os.kill(pid, signal.SIGKILL)
        start = current_time(session, "uav_a")
        assert start is not None
        wait_until(lambda: (now := current_time(session, "uav_a")) is not None and now.t >= start.t + 10.0, 60,
                   "the leader stepping 10 simulated seconds after its follower died")
    finally:
        gate.leave()
        session.close()
        station.gcs.close()
