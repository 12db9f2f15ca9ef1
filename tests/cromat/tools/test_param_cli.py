"""``cromat param`` end to end (issue 34): ``cromat launch`` of a robot with the trajectory generator (which takes
its limits at run time), a test module that declares no params, and the RAL; the CLI over the MRI on the real bus.

By effect: a change set at run time is in the next path the generator plans, is kept when the module restarts, and
comes out as a ``param_changed`` GRI event; every refused change (wrong type, out of range, unknown, start-up only)
says why and changes nothing (the next path, the listing and the GRI events as before)."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts import gri, mri
from bbcs.contracts.path_follower import DatosSegCam
from bbcs.contracts.trajectory import SurveyRequest, TrajectoryRequest, Vertex
from bbcs.session import local_client, open_session
from bbcs.testing import child_env, wait_until

ROOT = Path(__file__).resolve().parents[3]
MM_TESTS = ROOT / "tests" / "module_manager"
sys.path.insert(0, str(MM_TESTS))
from launch_support import Launch  # noqa: E402

POLYGON = [Vertex(lat=37.4260, lon=-6.0040), Vertex(lat=37.4260, lon=-5.9960),
           Vertex(lat=37.4290, lon=-5.9960), Vertex(lat=37.4290, lon=-6.0040)]
HEIGHT = 80.0

MANIFEST = f"""
pythonpath = ["{MM_TESTS}"]

[robot]
name = "r1"
kind = "test"
conf = "{ROOT / 'bbcs_conf' / 'uav1.conf'}"
state_period_s = 0.2

[bus]
listen = ["tcp/127.0.0.1:{{port:router}}"]

[supervision]
restart = "on-failure"
start_timeout_s = 40.0
watchdog_s = 0

[modules.trajectory]
entry = "modules.trajectory"
class = "modules.trajectory.module:TrajectoryModule"
params = {{ ground_altitude = "12", speed = "10" }}

[modules.src_a]
entry = "mm_source"
class = "mm_modules:Source"
params = {{ period_ms = "50" }}

[modules.ral]
entry = "ral"
class = "ral.module:Ral"
"""


def cromat_param(port: int, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "cromat", "param", "--connect", f"tcp/127.0.0.1:{port}",
                           "--timeout", "5", *args], cwd=str(ROOT), env=child_env(), capture_output=True, text=True,
                          timeout=60)


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory):
    tmp = tmp_path_factory.mktemp("param")
    manifest = tmp / "robot.toml"
    manifest.write_text(MANIFEST)
    launch = Launch(manifest, tmp)
    session = None
    subs: list = []
    try:
        launch.wait_line("all 3 modules up", 90)
        session = open_session(local_client(launch.port))
        paths: list[DatosSegCam] = []
        events: list[gri.GriEvent] = []
        lock = threading.Lock()
        decode_path = msgspec.msgpack.Decoder(DatosSegCam).decode

        def keep(into: list, value: object) -> None:
            with lock:
                into.append(value)

        subs.append(session.declare_subscriber(keys.slot_key("r1", "trajectory", "survey"),
                                               lambda s: keep(paths, decode_path(s.payload.to_bytes()))))
        subs.append(session.declare_subscriber(gri.events_key("r1"),
                                               lambda s: keep(events, gri.decode_event(s.payload.to_bytes()))))
        seq = iter(range(1, 1000))

        def altitude() -> float:
            """Plan one survey now; the altitude of its path (ground_altitude + the request's height)."""
            with lock:
                before = len(paths)
            req = TrajectoryRequest(request_id=next(seq), survey=SurveyRequest(polygon=POLYGON, height=HEIGHT,
                                                                               overlap=0.2))
            session.put(keys.slot_key("r1", "trajectory", "request"), msgspec.msgpack.encode(req))
            wait_until(lambda: len(paths) > before, 20, "the planned path")
            with lock:
                return {p.altura for p in paths[before].puntos}.pop()

        def param_events() -> list[str]:
            with lock:
                return [e.detail for e in events if e.kind == "param_changed"]

        yield launch, session, altitude, param_events
    finally:
        for sub in subs:
            sub.undeclare()
        if session is not None:
            session.close()
        try:
            launch.stop()
        finally:
            launch.cleanup()


def test_list_shows_types_ranges_values_and_what_is_settable(robot) -> None:
    launch, *_ = robot
    shown = cromat_param(launch.port, "list", "r1", "trajectory")
    assert shown.returncode == 0, shown.stderr
    rows = {line.split()[0]: line for line in shown.stdout.splitlines()[1:] if line and not line.startswith("(")}
    assert set(rows) == {"speed", "max_bank_deg", "ground_altitude", "line_extension", "arc_step_deg", "max_points"}
    assert rows["max_bank_deg"].split()[:4] == ["max_bank_deg", "float", "25.0", "25.0"]
    assert "> 0, < 90" in rows["max_bank_deg"] and rows["max_bank_deg"].endswith("settable")
    assert rows["ground_altitude"].split()[2] == "12.0", "the manifest's value"
    undeclared = cromat_param(launch.port, "list", "r1", "src_a", "--json")
    assert undeclared.returncode == 0, undeclared.stderr
    listing = msgspec.json.decode(undeclared.stdout)
    assert listing["declared"] is False
    assert [(p["name"], p["value"], p["settable"]) for p in listing["params"]] == [("period_ms", "50", False)]
    assert "declares no parameter struct" in listing["params"][0]["why"]


def test_a_set_takes_effect_is_kept_on_restart_and_is_a_gri_event(robot) -> None:
    launch, session, altitude, param_events = robot
    assert altitude() == 12.0 + HEIGHT
    done = cromat_param(launch.port, "set", "r1", "trajectory", "ground_altitude", "30")
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "r1/trajectory.ground_altitude = 30.0"
    assert altitude() == 30.0 + HEIGHT, "the next path is planned with the new value"
    wait_until(lambda: param_events() == ["trajectory.ground_altitude = 30.0 (was 12.0)"], 15, "the GRI event")
    got = cromat_param(launch.port, "get", "r1", "trajectory", "ground_altitude", "--json")
    assert msgspec.json.decode(got.stdout)["params"][0]["value"] == 30.0
    restarted = mri.call(session, "r1", "module", mri.ModuleCommand(module="trajectory", action="restart"), 60)
    assert restarted.ok, restarted.reason
    assert altitude() == 30.0 + HEIGHT, "a restarted module starts with the value set at run time"


REFUSED = [
    (("trajectory", "speed", "fast"), "trajectory.speed: bad value 'fast': Expected `float`"),
    (("trajectory", "max_bank_deg", "95"), "trajectory.max_bank_deg: bad value '95': Expected `float` < 90"),
    (("trajectory", "max_points", "1.5"), "trajectory.max_points: bad value '1.5': Expected `int`"),
    (("trajectory", "sped", "11"), "trajectory has no parameter 'sped' (did you mean speed?"),
    (("src_a", "period_ms", "5"), "module src_a declares no parameter struct: its params are read at start-up only"),
    (("ghost", "speed", "5"), "no module 'ghost' in robot 'r1'"),
]


@pytest.mark.parametrize("what,reason", REFUSED, ids=[f"{w[0]}.{w[1]}={w[2]}" for w, _ in REFUSED])
def test_a_refused_set_says_why_and_changes_nothing(robot, what, reason) -> None:
    launch, _, altitude, param_events = robot
    before_alt, before_events = altitude(), param_events()
    before = cromat_param(launch.port, "list", "r1", "trajectory", "--json").stdout
    refused = cromat_param(launch.port, "set", "r1", *what)
    assert refused.returncode == 1 and refused.stdout == ""
    assert reason in refused.stderr, refused.stderr
    assert altitude() == before_alt
    assert cromat_param(launch.port, "list", "r1", "trajectory", "--json").stdout == before
    assert param_events() == before_events


def test_start_up_only_parameter_of_a_declared_module_is_refused_with_its_reason() -> None:
    """A declared parameter not in the class's runtime_params: refused by the manager's check, naming what to do
    instead (the check the manager and the module share, bbcs.params.check_set)."""
    from bbcs.params import check_set
    from modules.trajectory.generator import Limits

    why = check_set("trajectory", Limits, frozenset({"speed"}), "max_points", "10")
    assert why == ("trajectory.max_points is read at start-up only: change modules.trajectory.params.max_points "
                   "in the manifest and restart trajectory")
    assert check_set("trajectory", Limits, frozenset({"speed"}), "speed", "12") == ""


def test_no_robot_is_exit_3() -> None:
    from bbcs.net import free_port

    gone = cromat_param(free_port(), "list", "r1", "trajectory")
    assert gone.returncode == 3 and "cannot reach the robot router" in gone.stderr


def test_the_manager_refuses_a_declared_start_up_only_parameter_before_asking_anyone() -> None:
    """The shipped vision module declares its params (typed) and none settable at run time: the manager's answer
    names the reason, and neither the module nor the record is touched (no session is even given)."""
    from bbcs.contracts.params import ListParams, SetParam
    from module_manager.manifest import load_manifest
    from module_manager.params import ParamDesk
    from modules.vision.module import VisionParams

    m = load_manifest(ROOT / "bbcs_conf" / "uav1_sim.toml")
    assert m.modules["vision"].params_type is VisionParams and m.modules["vision"].runtime_params == frozenset()
    desk = ParamDesk("uav1")
    infos = {n: i for n, i in m.modules.items()}

    def nobody(*_: object) -> None:
        raise AssertionError("nothing may be asked or recorded for a refused change")

    listing = desk.handle(ListParams(module="vision"), infos, lambda v: v, nobody, None, nobody, nobody)
    assert listing.ok and listing.data.declared and listing.data.params
    assert all(not p.settable and "read at start-up only" in p.why for p in listing.data.params)
    name = listing.data.params[0].name
    refused = desk.handle(SetParam(module="vision", name=name, value="1"), infos, lambda v: v, nobody, None, nobody,
                          nobody)
    assert not refused.ok and refused.reason == (f"vision.{name} is read at start-up only: change modules.vision."
                                                 f"params.{name} in the manifest and restart vision; nothing changed")
    assert desk.recent() == [] and desk.overrides == {}
