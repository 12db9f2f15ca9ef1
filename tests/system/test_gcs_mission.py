"""Issue 6 end to end: ``cromat launch bbcs_conf/uav1_sim.toml`` (router, DSP simulator, DSP, telemetry, pan &
tilt, path follower, vision, RAL — the real Module Manager) as a process tree, and a ground station using
the GCS Python API over TCP: it sees the robot, watches its state, takes off, flies a 10-waypoint path to
completion, swaps the pan & tilt DATOS input to the vision target and back, tracks, and aborts mid-path.

What the simulated DSP received is read from its ``--record`` file (every command frame, in order).
:class:`SimRobot` is shared with the other ``test_gcs_*`` files.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from bbcs.contracts import gri
from bbcs.testing import wait_until
from ral.gcs.api import Gcs, session_config

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "module_manager"))
from launch_support import ROOT, Launch  # noqa: E402

from modules.dsp.sim.record import read_record

ROBOT = "uav1"
MANIFEST = ROOT / "bbcs_conf" / "uav1_sim.toml"
TIME_SCALE = 4.0
"""Simulated seconds per wall second: the flight takes a quarter of real time."""
N_MODULES = 6


def sim_manifest(
    tmp_path: Path,
    *,
    ral: dict[str, str] | None = None,
    edit: Callable[[str], str] | None = None,
    time_scale: float = TIME_SCALE,
    lockstep: bool = False,
) -> tuple[Path, Path]:
    """uav1_sim.toml with an absolute .conf, the simulator recording into ``tmp_path`` and sped up, and some
    RAL parameters overridden. Returns (manifest, record file).

    ``lockstep``: the robot in lockstep (``[sim] lockstep = true``, docs/simulation.md); the simulator's
    ``--time-scale`` then only paces it when the launch gives no ``--speed``."""
    record = tmp_path / "dsp_record.jsonl"
    text = MANIFEST.read_text()
    text = text.replace('conf = "uav1.conf"', f'conf = "{MANIFEST.parent / "uav1.conf"}"')
    old = '"--tcp", "127.0.0.1:{port:dsp}"]'
    assert old in text, "the DSP simulator's command line in uav1_sim.toml changed"
    text = text.replace(
        old, f'"--tcp", "127.0.0.1:{{port:dsp}}", "--time-scale", "{time_scale:g}", "--record", "{record}"]'
    )
    for key, value in (ral or {}).items():
        text, n = _replace_param(text, key, value)
        assert n == 1, f"RAL parameter {key} not in the manifest"
    if lockstep and "lockstep = true" not in text:
        assert "\n[bus]\n" in text, "uav1_sim.toml has no [bus] table to put [sim] before"
        text = text.replace("\n[bus]\n", "\n[sim]\nlockstep = true\n\n[bus]\n", 1)
    if edit is not None:
        text = edit(text)
    path = tmp_path / "uav1_sim.toml"
    path.write_text(text)
    return path, record


def _replace_param(text: str, key: str, value: str) -> tuple[str, int]:
    import re

    return re.subn(rf'(\[modules\.ral\][^\[]*?params = {{[^}}]*\b{key} = )"[^"]*"', rf'\g<1>"{value}"', text)


class SimRobot:
    """One launched robot plus the ground station's view of it (latest state, every event)."""

    def __init__(self, launch: Launch, gcs: Gcs, record: Path) -> None:
        self.launch = launch
        self.gcs = gcs
        self.record = record
        self.lock = threading.Lock()
        self.states: list[gri.GriState] = []
        self.received = 0
        """GRI states received so far (``states`` keeps only the last 50)."""
        self.events: list[gri.GriEvent] = []
        gcs.watch(ROBOT, self._on_state)
        gcs.events(ROBOT, self._on_event)

    def _on_state(self, state: gri.GriState) -> None:
        with self.lock:
            self.states.append(state)
            self.received += 1
            del self.states[:-50]

    def _on_event(self, event: gri.GriEvent) -> None:
        with self.lock:
            self.events.append(event)

    @property
    def state(self) -> gri.GriState:
        with self.lock:
            return self.states[-1]

    def wait_state(self, pred: Callable[[gri.GriState], bool], timeout_s: float, what: str) -> gri.GriState:
        try:
            wait_until(lambda: bool(self.states) and pred(self.state), timeout_s, what)
        except AssertionError as exc:
            raise AssertionError(f"{exc}\n{self.describe()}") from None
        return self.state

    def describe(self) -> str:
        """What the station last saw (the newest state, the last events): a timed-out wait's evidence."""
        with self.lock:
            state = self.states[-1] if self.states else None
            events = self.events[-12:]
            received = self.received
        lines = [f"{received} states received"]
        if state is not None:
            tel = state.telemetry
            lines.append(
                f"last state: stamp {state.stamp:.2f}, manager_up {state.manager_up}, link {state.link}, "
                f"queued {state.waypoints_queued}, airborne {state.airborne}, "
                f"telemetry stamp {tel.stamp if tel else None}"
            )
            lines += [f"  task {t.task_type} {t.name} {t.kind} #{t.id} {t.status} {t.origin}" for t in state.tasks]
            lines += [f"  error {e.module}: {e.code} {e.name} {e.detail}" for e in state.errors[-5:]]
        lines += [f"  event {e.stamp:.2f} {e.kind} task {e.task_id} {e.detail}" for e in events]
        return "\n".join(lines)

    def wait_event(
        self, pred: Callable[[gri.GriEvent], bool], timeout_s: float, what: str, after: int = 0
    ) -> gri.GriEvent:
        found: list[gri.GriEvent] = []

        def seen() -> bool:
            with self.lock:
                found[:] = [e for e in self.events[after:] if pred(e)]
            return bool(found)

        wait_until(seen, timeout_s, what)
        return found[0]

    def commands(self) -> list[dict]:
        """Every command frame the simulated DSP received so far (its record file)."""
        return read_record(self.record)

    def ensure_airborne(self, height: float = 10.0) -> gri.GriState:
        state = self.wait_state(
            lambda s: s.position is not None and s.airborne is not None,
            30,
            "robot telemetry in the GRI state",
        )
        if state.airborne:
            return state
        start = len(self.events)
        reply = self.gcs.send(ROBOT, gri.TakeOff(height=height))
        assert reply.accepted, reply.reason
        self.wait_event(
            lambda e: e.kind == "task_completed" and e.task_id == reply.task_id,
            30,
            "take-off completed",
            after=start,
        )
        # the GRI state's telemetry comes with the manager's state, later than the event: wait for the height
        return self.wait_state(
            lambda s: bool(s.airborne) and s.position is not None and s.home is not None
            and s.position.alt >= s.home.alt + height - 2.0,
            15,
            "airborne at the take-off height",
        )


GRID_DEG = 1e-4
"""The DSP protocol carries waypoint lat/lon as degrees × 10^4 (≈ 11 m): test paths lie on that grid so what
the DSP receives equals what the GCS sent."""
LOOP = [(1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (2, -1), (2, 0)]
"""Ten waypoints around the start, in grid steps (north, east)."""


def grid_path(center: object, steps: list[tuple[int, int]] = LOOP, scale: int = 1) -> list[gri.Waypoint]:
    """Waypoints ``steps`` × ``scale`` grid cells from ``center`` (a GeoPoint, snapped to the grid)."""
    lat0 = round(center.lat / GRID_DEG) * GRID_DEG  # type: ignore[attr-defined]
    lon0 = round(center.lon / GRID_DEG) * GRID_DEG  # type: ignore[attr-defined]
    alt = center.alt  # type: ignore[attr-defined]
    return [
        gri.Waypoint(
            lat=round(lat0 + n * scale * GRID_DEG, 4), lon=round(lon0 + e * scale * GRID_DEG, 4), alt=alt
        )
        for n, e in steps
    ]


def launch_robot(tmp_path: Path, speed: str | None = "max", **manifest_kw) -> tuple[Launch, Path]:
    """The robot launched (``sim_manifest``'s options); with ``lockstep=True`` at ``--speed`` ``speed``, or with
    ``speed=None`` paced by the simulator's ``--time-scale`` (``sim_manifest``'s ``time_scale``): a robot that
    waits on the wall clock for most of a test (replies, the link failsafe) then spends no processor time
    stepping ahead while it waits."""
    manifest, record = sim_manifest(tmp_path, **manifest_kw)
    paced = manifest_kw.get("lockstep") and speed is not None
    la = Launch(manifest, tmp_path, *(("--speed", speed) if paced else ()))
    try:
        la.wait_line(f"all {N_MODULES} modules up", 90)
    except BaseException:
        la.cleanup()
        raise
    return la, record


def connect(port: int, name: str = "gcs", link: bool = True) -> Gcs:
    return Gcs(session_config([f"tcp/127.0.0.1:{port}"]), name=name, link=[ROBOT] if link else [], timeout_s=10.0)


@pytest.fixture
def robot(tmp_path: Path) -> Iterator[SimRobot]:
    """The shipped robot in lockstep at ``--speed max`` (docs/simulation.md)."""
    la, record = launch_robot(tmp_path, lockstep=True)
    gcs = None
    try:
        gcs = connect(la.port, "ground1")
        yield SimRobot(la, gcs, record)
    finally:
        if gcs is not None:
            gcs.close()
        la.stop()
        la.cleanup()


def test_gcs_flies_ten_waypoints_swaps_pan_tilt_source_and_aborts(robot: SimRobot) -> None:
    gcs = robot.gcs
    # sees the robot, watches its state
    wait_until(lambda: gcs.robots(1.0) == [ROBOT], 30, "the robot in the GCS's robot list")
    first = robot.wait_state(
        lambda s: s.link == "up" and s.manager_up and s.position is not None,
        30,
        "state with position, manager up and this GCS linked",
    )
    assert first.kind == "uav"
    assert {m.name: m.state for m in first.modules} == {
        "dsp": "up",
        "telemetry": "up",
        "pan_tilt": "up",
        "path_follower": "up",
        "vision": "up",
        "ral": "up",
    }
    assert {
        "goto",
        "follow_path",
        "take_off",
        "land",
        "look_at",
        "pan_tilt",
        "hold",
        "track",
        "follow_vision_path",
        "bridge",
    } <= set(first.available)
    assert "abort" not in first.available, "abort is a request of its own, not a task a station sends"

    # take off if needed, then a 10-waypoint path to completion
    up = robot.ensure_airborne()
    assert up.position is not None and up.home is not None
    path = grid_path(up.position)
    before = len(robot.commands())
    start = len(robot.events)
    reply = gcs.send(ROBOT, gri.FollowPath(waypoints=path, speed=5.0))
    assert reply.accepted and reply.task_type == "movement", reply.reason
    robot.wait_state(lambda s: bool(s.waypoints_queued), 20, "the DSP's waypoint queue filled")
    done = robot.wait_event(
        lambda e: e.task_id == reply.task_id and e.kind != "task_accepted",
        60,
        "the path task ended",
        after=start,
    )
    assert done.kind == "task_completed", done
    added = [c for c in robot.commands()[before:] if c["name"] == "ADD_WAYPOINT"]
    assert [(round(c["fields"]["lat"], 4), round(c["fields"]["lon"], 4)) for c in added] == [
        (w.lat, w.lon) for w in path
    ]
    # the state comes with the manager's (1 Hz), after the event: wait for it to show the task gone
    end = robot.wait_state(lambda s: s.waypoints_queued == 0 and not any(t.kind == "follow_path" for t in s.tasks),
                           15, "queue empty and the task gone from the state")
    assert end.position is not None
    assert abs(end.position.lat - path[-1].lat) * 111_320 < 3.0

    # pan & tilt angles from the GCS slot, then DATOS swapped to the vision target and back
    reply = gcs.send(ROBOT, gri.SetPanTilt(pan=30.0, tilt=-20.0))
    assert reply.accepted, reply.reason
    robot.wait_state(lambda s: s.pan_deg is not None and abs(s.pan_deg - 30.0) < 2.0, 15, "pan at 30 degrees")
    routes = gcs.route(ROBOT, "pan_tilt", "datos", 20)
    assert routes.routes["pan_tilt"]["datos"] == 20 and routes.slots[20] == "vision/target"
    assert {m.name: m.routes for m in gcs.modules(ROBOT).modules}["pan_tilt"]["datos"] == 20
    routes = gcs.route(ROBOT, "pan_tilt", "datos", 10)
    assert routes.routes["pan_tilt"]["datos"] == 10 and routes.slots[10] == "ral/pt_datos"
    # a swap to a slot of another type is refused and the route kept
    with pytest.raises(Exception, match="refused"):
        gcs.route(ROBOT, "pan_tilt", "datos", 11)
    assert gcs.routes(ROBOT).routes["pan_tilt"]["datos"] == 10
    # GCS angles reach the DSP again after the swap back
    reply = gcs.send(ROBOT, gri.SetPanTilt(pan=-45.0, tilt=-10.0))
    assert reply.accepted, reply.reason
    robot.wait_state(
        lambda s: s.pan_deg is not None and abs(s.pan_deg + 45.0) < 2.0, 15, "pan at -45 degrees"
    )

    # perception task: the pan & tilt follows the vision target (mode 1)
    reply = gcs.send(ROBOT, gri.Track())
    assert reply.accepted and reply.task_type == "perception", reply.reason
    assert {m.name: m.routes for m in gcs.modules(ROBOT).modules}["pan_tilt"]["datos"] == 20
    robot.wait_state(lambda s: any(t.kind == "track" for t in s.tasks), 15, "track running")

    # abort mid-path: the DSP queue empties, every task ends, the pan & tilt input is restored
    far = grid_path(end.position, scale=6)
    reply = gcs.send(ROBOT, gri.FollowPath(waypoints=far, speed=5.0))
    assert reply.accepted, reply.reason
    robot.wait_state(lambda s: (s.waypoints_queued or 0) >= 5, 20, "mid-path")
    start = len(robot.events)
    n_cmd = len(robot.commands())
    reply = gcs.abort(ROBOT)
    assert reply.accepted, reply.reason
    wait_until(lambda: "ABORT" in [c["name"] for c in robot.commands()[n_cmd:]], 15, "Abort reached the DSP")
    robot.wait_state(lambda s: s.waypoints_queued == 0 and not s.tasks, 15, "queue empty and no task")
    wait_until(
        lambda: (
            {e.task_type for e in robot.events[start:] if e.kind == "aborted"}
            == {"movement", "pan_tilt", "perception"}
        ),
        15,
        "an aborted event for each running task",
    )
    assert gcs.routes(ROBOT).routes["pan_tilt"]["datos"] == 10
    assert robot.state.airborne  # abort holds; it does not land
