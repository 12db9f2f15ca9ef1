"""``cromat launch`` as a real process tree: comes up, stops with nothing left, restarts, gives up, routes."""

from __future__ import annotations

import json
import os
import signal
import socket
import sys
import threading
from pathlib import Path

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts import mri
from bbcs.errors import EXIT_CONFIG
from bbcs.testing import wait_until

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch_support import ROOT, Launch, describe, group_members, write_manifest  # noqa: E402

UP = "all 3 modules up"
MRI_S = 20.0
"""MRI reply deadline: route swaps and tasks wait up to 5 s for module acknowledgements inside the manager."""


@pytest.fixture
def launch(tmp_path):
    started: list[Launch] = []

    def make(*extra: str, edit=None) -> Launch:
        launch = Launch(write_manifest(tmp_path, edit=edit), tmp_path, *extra)
        started.append(launch)
        return launch

    try:
        yield make
    finally:
        for launch in started:
            launch.cleanup()


def sink_records(tmp_path: Path) -> list[dict]:
    path = tmp_path / "sink.jsonl"
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.endswith("}")]


def modules(session, robot: str = "r1") -> dict[str, mri.ModuleStatus]:
    reply = mri.call(session, robot, "modules", mri.ListModules(), MRI_S)
    assert reply.ok and isinstance(reply.data, mri.ModuleList)
    return {m.name: m for m in reply.data.modules}


def test_comes_up_and_sigterm_leaves_no_process(launch):
    la = launch()
    la.wait_line(UP)
    def up() -> list[str]:
        return sorted(line.split()[0] for line in list(la.lines) if line.split()[1:2] == ["up"])

    wait_until(lambda: up() == ["sink", "src_a", "src_b"], 30, "one status line per module once up")
    assert len(group_members(la.pgid)) >= 5, "manager, router and three modules"
    assert la.stop(signal.SIGTERM) == 0
    wait_until(lambda: group_members(la.pgid) == [], 30, "every child of the launch gone")


def simulator_never_ready(text: str) -> str:
    """A simulator whose readiness never comes: the launch gives up after its 1 s before any module starts."""
    return text + """
[processes.never_ready]
command = ["{python}", "-c", "import time; time.sleep(120)"]
ready = { kind = "stdout", pattern = "never printed", timeout_s = 1.0 }
"""


def test_a_launch_that_fails_before_its_modules_start_leaves_nothing(launch, tmp_path):
    """The modules' interpreters are started ahead, before the router: a launch that gives up before their start
    takes them down too, and no module ever ran (no record, no bus)."""
    la = launch(edit=simulator_never_ready)
    assert la.proc.wait(60) == 1
    la.reader.join(5)
    out = "\n".join(la.lines)
    assert "process never_ready" in out and "not ready within 1 s" in out, out
    assert "starting" not in out, "no module was started"
    assert not (tmp_path / "sink.jsonl").exists(), "the sink never ran"
    wait_until(lambda: group_members(la.pgid) == [], 30, "every child of the launch gone, standbys included")


def test_ctrl_c_to_the_process_group_leaves_no_process(launch):
    la = launch()
    la.wait_line(UP)
    os.killpg(la.pgid, signal.SIGINT)  # what a terminal does on Ctrl+C
    assert la.stop(signal.SIGINT) == 0
    wait_until(lambda: group_members(la.pgid) == [], 30, "every child of the launch gone")


def test_manager_sigkilled_leaves_no_orphan(launch):
    la = launch()
    la.wait_line(UP)
    assert len(group_members(la.pgid)) >= 5
    la.proc.kill()
    la.proc.wait(30)
    try:
        wait_until(lambda: group_members(la.pgid) == [], 30, "children to die with the manager (PR_SET_PDEATHSIG)")
    except AssertionError as exc:
        raise AssertionError(f"{exc}; still there:\n{describe(group_members(la.pgid))}") from None


def test_kill9_module_is_restarted_with_its_current_routing(launch, clients, tmp_path):
    la = launch()
    la.wait_line(UP)
    s = clients(la.port)
    swap = mri.call(s, "r1", "route", mri.SwapRoute(module="sink", input="datos", slot=2), MRI_S)
    assert swap.ok, swap.reason
    before = modules(s)["sink"]
    assert before.state == "up" and before.pid is not None
    os.kill(before.pid, signal.SIGKILL)
    la.wait_line("killed by signal 9; restart in 0 s")  # a first failure: restarted with no backoff delay
    wait_until(lambda: (m := modules(s)["sink"]).state == "up" and m.pid != before.pid, 30, "sink restarted and up")
    after = modules(s)["sink"]
    assert after.restarts == 1
    assert after.last_exit == -signal.SIGKILL
    assert after.routes == {"datos": 2, "modo": 3}
    starts = [{k: v for k, v in r.items() if k != "t"} for r in sink_records(tmp_path) if r.get("event") == "start"]
    assert starts[-1] == {"module": "sink", "event": "start", "restart": 1, "routes": {"datos": 2, "modo": 3}}
    rows = sink_records(tmp_path)
    last_start = max(i for i, r in enumerate(rows) if r.get("event") == "start")
    # the last safe-state value (the manager's mode slot, advanced pub/sub history) reaches the new run
    wait_until(lambda: {"module": "sink", "slot": "modo", "mode": 0} in sink_records(tmp_path)[last_start:], 30,
               "the mode slot's last value handled by the restarted sink")
    n = len(sink_records(tmp_path))
    wait_until(lambda: any(r.get("slot") == "datos" for r in sink_records(tmp_path)[n:]), 30, "data after restart")
    assert {r["source"] for r in sink_records(tmp_path)[n:] if r.get("slot") == "datos"} == {"src_b"}
    la.wait_line("restarts 1")
    assert la.stop() == 0


def slow_src_a_sink_after_it(text: str) -> str:
    """src_a starts slowly (1.5 s in its on_start), the sink starts after src_a, src_b depends on nothing."""
    record = 'params = { record = "{manifest_dir}/sink.jsonl" }'
    text = text.replace('params = { period_ms = "5" }', 'params = { period_ms = "5", start_delay_ms = "1500", '
                        'record = "{manifest_dir}/sink.jsonl" }', 1)
    text = text.replace('params = { period_ms = "5" }', 'params = { period_ms = "5", '
                        'record = "{manifest_dir}/sink.jsonl" }', 1)
    return text.replace(record, record + '\nafter = ["src_a"]')


def test_modules_start_in_parallel_and_a_dependent_only_once_its_dependency_is_up(launch, tmp_path):
    la = launch(edit=slow_src_a_sink_after_it)
    la.wait_line(UP)
    rows = sink_records(tmp_path)
    ready = {r["module"]: r["t"] for r in rows if r.get("event") == "ready"}
    sink_start = next(r["t"] for r in rows if r.get("event") == "start")
    assert ready["src_b"] < ready["src_a"] - 1.0, "src_b did not wait for the slow src_a: they start in parallel"
    assert sink_start > ready["src_a"], "the sink started only after src_a (its 'after') was up"
    # "all up" is the modules' readiness, not their first datum: wait for the sink to handle one
    wait_until(lambda: any(r.get("slot") == "datos" for r in sink_records(tmp_path)), 30, "the sink's first datum")
    first = next(r for r in sink_records(tmp_path) if r.get("slot") == "datos")
    assert first["source"] == "src_a" and first["seq"] >= 1
    assert la.stop() == 0


def add_crasher(text: str) -> str:
    return text + """
[modules.crasher]
entry = "mm_sink"
class = "mm_modules:Sink"
params = { crash = "always" }
backoff_s = 0.05
intensity = 2
period_s = 60.0
"""


def test_always_crashing_module_is_failed_others_keep_running(launch, clients, tmp_path):
    la = launch(edit=add_crasher)
    la.wait_line("intensity exceeded", 60)
    s = clients(la.port)
    # the crasher can fail before the other modules have finished starting: they must come (and stay) up
    wait_until(lambda: all(m.state == "up" for n, m in modules(s).items() if n != "crasher"), 30, "the others up")
    status = modules(s)
    assert status["crasher"].state == "failed"
    assert status["crasher"].restarts == 2
    assert status["crasher"].last_exit == 3
    assert "intensity" in status["crasher"].reason
    assert all(status[n].state == "up" for n in ("src_a", "src_b", "sink"))
    states: list[mri.RobotState] = []
    got = threading.Event()
    decode = msgspec.msgpack.Decoder(mri.RobotState).decode

    def on_state(sample) -> None:
        states.append(decode(sample.payload.to_bytes()))
        got.set()

    sub = s.declare_subscriber(keys.manager_key("r1", "state"), on_state)
    try:
        assert got.wait(20), "robot state published periodically"
        state = states[-1]
        assert state.robot == "r1" and state.kind == "test"
        assert {m.name: m.state for m in state.modules}["crasher"] == "failed"
    finally:
        sub.undeclare()
    n = len(sink_records(tmp_path))
    wait_until(lambda: len(sink_records(tmp_path)) > n + 5, 30, "the sink still handling data")
    assert la.stop() == 0


def test_a_module_refusing_its_configuration_at_launch_stops_the_whole_launch(launch, tmp_path):
    """Issue 30 case 8: no half-started robot. The crasher exits EXIT_CONFIG on its first start: the launch says
    which module and why (its log's last line) and stops every module, exit 1, nothing left running."""
    la = launch(edit=lambda text: add_crasher(text).replace('crash = "always"', 'crash = "config"')
                .replace("intensity = 2", "intensity = 5"))
    assert la.proc.wait(60) == 1
    la.reader.join(10)
    out = "\n".join(la.lines)
    assert "module crasher exited 78: configuration error (mm_modules: invalid configuration (test))" in out, out
    assert "the robot is not started half-way, every module is stopped" in out
    assert "all 4 modules up" not in out
    assert group_members(la.pgid) == [], "processes of the launch left running"
    log = (tmp_path / "logs" / "crasher.log").read_text()
    assert log.count("invalid configuration (test)") == 1, "started exactly once"


def test_once_up_with_a_module_that_never_comes_up_exits_1_naming_it_and_why(launch):
    """``--once-up`` (the launch benchmark, a user checking a manifest) that gives up says which module failed
    and how; the modules that came up are not named."""
    la = launch("--once-up", edit=add_crasher)
    assert la.proc.wait(60) == 1
    la.reader.join(10)
    said = next(line for line in la.lines if "not every module came up" in line)
    named = said.split("not every module came up: ", 1)[1]
    assert named.startswith("crasher failed (exited with status 3; restart intensity exceeded"), said
    assert not any(f"{n} " in named for n in ("src_a", "src_b", "sink")), said
    assert group_members(la.pgid) == [], "processes of the launch left running"


def test_a_module_refusing_its_configuration_once_up_is_failed_and_not_retried(launch, clients, tmp_path):
    """Once the robot is up, a module whose restart refuses its configuration is failed, never retried, and the
    others keep running (a robot in flight is not stopped for it)."""
    la = launch(edit=lambda text: add_crasher(text).replace('crash = "always"', 'crash = "config_on_restart"')
                .replace("intensity = 2", "intensity = 5"))
    la.wait_line("all 4 modules up", 60)
    s = clients(la.port)
    os.kill(modules(s)["crasher"].pid, signal.SIGKILL)
    la.wait_line("configuration error", 30)
    wait_until(lambda: modules(s)["crasher"].state == "failed", 10, "the crasher failed")
    status = modules(s)
    assert status["crasher"].restarts == 1 and status["crasher"].last_exit == EXIT_CONFIG
    assert "configuration error" in status["crasher"].reason and "not restarted" in status["crasher"].reason
    assert all(status[n].state == "up" for n in ("src_a", "src_b", "sink")) and la.proc.poll() is None
    assert la.stop() == 0


def test_launch_with_an_invalid_conf_stops_before_anything_starts(tmp_path):
    """The UAV's manifest with MAX_SPEED: fast and a misspelt TELEMETRY field: both reported with the .conf's
    file:line, exit 2, and no router, simulator or module was started (no log file, the port stays closed)."""
    conf_dir = ROOT / "bbcs_conf"
    conf = tmp_path / "uav1.conf"
    text = (conf_dir / "uav1.conf").read_text()
    conf.write_text(text.replace("MAX_SPEED: 8.0", "MAX_SPEED: fast").replace("NAV, SPEED", "NAV, SPED"))
    lines = conf.read_text().splitlines()
    speed_line = next(i for i, t in enumerate(lines, 1) if t.startswith("MAX_SPEED"))
    telemetry_line = next(i for i, t in enumerate(lines, 1) if t.startswith("TELEMETRY:"))
    manifest = tmp_path / "uav1_sim.toml"
    manifest.write_text((conf_dir / "uav1_sim.toml").read_text().replace('conf = "uav1.conf"', f'conf = "{conf}"'))
    la = Launch(manifest, tmp_path)
    try:
        assert la.proc.wait(60) == 2
        la.reader.join(10)
        out = "\n".join(la.lines)
        assert f"{conf}:{speed_line}:1: key 'MAX_SPEED': invalid value 'fast'" in out, out
        assert f"{conf}:{telemetry_line}:1: key 'TELEMETRY'" in out and "'SPED'" in out, out
        assert not (tmp_path / "logs").exists(), "no child was started"
        with pytest.raises(OSError):
            socket.create_connection(("127.0.0.1", la.port), timeout=1).close()
    finally:
        la.cleanup()


def test_swap_route_through_mri_while_data_flow(launch, clients, tmp_path):
    la = launch()
    la.wait_line(UP)
    s = clients(la.port)
    wait_until(lambda: any(r.get("source") == "src_a" for r in sink_records(tmp_path)), 30, "data from src_a")
    for bad, why in ((4, "carries"), (99, "not in the slot table")):
        reply = mri.call(s, "r1", "route", mri.SwapRoute(module="sink", input="datos", slot=bad), MRI_S)
        assert not reply.ok and why in reply.reason and "old route kept" in reply.reason
        assert isinstance(reply.data, mri.RouteList) and reply.data.routes["sink"]["datos"] == 1
    reply = mri.call(s, "r1", "route", mri.SwapRoute(module="nosuch", input="datos", slot=2), MRI_S)
    assert not reply.ok and "nosuch" in reply.reason
    reply = mri.call(s, "r1", "route", mri.SwapRoute(module="sink", input="datos", slot=2), MRI_S)
    assert reply.ok, reply.reason
    assert isinstance(reply.data, mri.RouteList) and reply.data.routes["sink"]["datos"] == 2
    records = sink_records(tmp_path)
    switch = max(i for i, r in enumerate(records) if r.get("event") == "route" and r["routes"]["datos"] == 2)
    wait_until(lambda: sum(r.get("source") == "src_b" for r in sink_records(tmp_path)) > 10, 30, "data from src_b")
    after = [r["source"] for r in sink_records(tmp_path)[switch:] if r.get("slot") == "datos"]
    assert set(after) == {"src_b"}, "only the new source is used after the acknowledged switch"
    assert "src_a" in {r.get("source") for r in records[:switch]}
    assert la.stop() == 0


def test_tasks_modes_and_robot_state_errors(launch, clients, tmp_path):
    la = launch()
    la.wait_line(UP)
    s = clients(la.port)
    tasks = mri.call(s, "r1", "tasks", mri.ListTasks(), MRI_S)
    assert tasks.ok and tasks.data.available == {"follow_b": "perception", "ignore_all": "perception"}
    reply = mri.call(s, "r1", "task", mri.SetTask(name="follow_b"), MRI_S)
    assert reply.ok, reply.reason
    assert [t.name for t in reply.data.active] == ["follow_b"]
    routes = mri.call(s, "r1", "routes", mri.ListRoutes(), MRI_S).data
    assert routes.routes["sink"]["datos"] == 2
    wait_until(lambda: {"module": "sink", "slot": "modo", "mode": 1} in sink_records(tmp_path), 30, "task mode 1")
    reply = mri.call(s, "r1", "task", mri.SetTask(name="ignore_all"), MRI_S)
    assert reply.ok and [t.name for t in reply.data.active] == ["ignore_all"], "replaces the task of its type"
    assert mri.call(s, "r1", "routes", mri.ListRoutes(), MRI_S).data.routes["sink"]["datos"] == -1
    reply = mri.call(s, "r1", "task", mri.EndTask(task_type="perception"), MRI_S)
    assert reply.ok and reply.data.active == []
    assert mri.call(s, "r1", "routes", mri.ListRoutes(), MRI_S).data.routes["sink"]["datos"] == 1, "routes restored"
    wait_until(lambda: [r for r in sink_records(tmp_path) if r.get("slot") == "modo"][-1]["mode"] == 0, 30,
               "mode restored to the one before the first task")
    reply = mri.call(s, "r1", "task", mri.EndTask(task_type="perception"), MRI_S)
    assert not reply.ok and "no perception task" in reply.reason
    assert not mri.call(s, "r1", "task", mri.SetTask(name="nosuch"), MRI_S).ok
    bad = mri.call(s, "r1", "mode", mri.SetModuleMode(module="sink", mode={"mode": 7}), MRI_S)
    assert not bad.ok and "refused" in bad.reason
    assert mri.call(s, "r1", "mode", mri.SetModuleMode(module="sink", mode={"mode": 2}), MRI_S).ok
    wait_until(lambda: modules(s)["sink"].last_error == 142, 30, "the sink's error code in the module status")
    wrong = mri.call(s, "r1", "modules", mri.ListRoutes(), MRI_S)
    assert not wrong.ok and "ListModules" in wrong.reason
    assert la.stop() == 0


def test_module_stop_start_restart_through_mri(launch, clients):
    la = launch()
    la.wait_line(UP)
    s = clients(la.port)
    reply = mri.call(s, "r1", "module", mri.ModuleCommand(module="src_a", action="stop"), timeout_s=15)
    assert reply.ok and reply.data.state == "stopped"
    assert modules(s)["src_a"].pid is None
    reply = mri.call(s, "r1", "module", mri.ModuleCommand(module="src_a", action="start"), timeout_s=30)
    assert reply.ok and reply.data.state == "up"
    pid = reply.data.pid
    reply = mri.call(s, "r1", "module", mri.ModuleCommand(module="src_a", action="restart"), timeout_s=30)
    assert reply.ok and reply.data.state == "up" and reply.data.pid != pid
    assert reply.data.restarts == 0, "operator restarts are not failures"
    assert la.stop() == 0


def test_sigterm_after_the_reader_of_its_output_went_away_still_stops_everything(tmp_path):
    """A launch whose stdout reader died (the terminal or the test runner that started it was killed) still stops
    every module and exits on SIGTERM: a write to the closed pipe must not cut its shutdown short."""
    import subprocess

    from bbcs.testing import child_env, free_port

    proc = subprocess.Popen(
        [sys.executable, "-m", "module_manager.cli", str(write_manifest(tmp_path)), "--listen",
         f"tcp/127.0.0.1:{free_port()}", "--log-dir", str(tmp_path / "logs"), "--status-interval", "0.2"],
        cwd=str(ROOT), env=child_env(), stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        start_new_session=True)
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # no reader thread: this test owns the pipe and closes it
            if UP in line:
                break
        assert len(group_members(proc.pid)) >= 5, "manager, router and three modules"
        proc.stdout.close()  # the reader goes away: the manager's next status line hits a closed pipe
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) in (0, 1)
        wait_until(lambda: group_members(proc.pid) == [], 30, "every child of the launch gone")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        for pid in group_members(proc.pid):
            os.kill(pid, signal.SIGKILL)


def test_config_refusals_are_the_modules_failed_on_their_configuration() -> None:
    from module_manager.manager import config_refusals
    from module_manager.supervision import Phase

    assert config_refusals({"a": (Phase.UP, None), "b": (Phase.FAILED, 3), "c": (Phase.STARTING, EXIT_CONFIG)}) == []
    assert config_refusals({"a": (Phase.FAILED, EXIT_CONFIG), "b": (Phase.FAILED, 1), "c": (Phase.UP, EXIT_CONFIG),
                            "d": (Phase.FAILED, EXIT_CONFIG)}) == ["a", "d"]
