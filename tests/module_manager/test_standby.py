"""Warm standbys (``standby = true``): a SIGKILLed module is replaced by its standby, which takes the current
routes and restart count from its first message and keeps the supervision rules; a stopped module has none and
starts cold; nothing is left behind. The preload itself imports what an entry imports and runs nothing else."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from bbcs.contracts import mri
from bbcs.testing import child_env, wait_until
from module_manager.standby import context_line, preload

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch_support import ROOT, Launch, cmdline, describe, group_members, standbys, write_manifest  # noqa: E402

UP = "all 3 modules up"
MRI_S = 20.0


def with_standby(text: str) -> str:
    # and a start timeout long enough for a machine loaded by the tests beside this one: what is tested here is
    # which process becomes the module, not how fast (a start that times out is killed and started again cold)
    text = text.replace("start_timeout_s = 20.0", "start_timeout_s = 60.0")
    return text.replace("period_s = 30.0", "period_s = 30.0\nstandby = true")


@pytest.fixture
def robot(tmp_path):
    la = Launch(write_manifest(tmp_path, edit=with_standby), tmp_path)
    try:
        la.wait_line(UP)
        yield la
    finally:
        la.cleanup()


def records(tmp_path: Path) -> list[dict]:
    return [json.loads(line) for line in (tmp_path / "sink.jsonl").read_text().splitlines() if line.endswith("}")]


def sink(session) -> mri.ModuleStatus:
    reply = mri.call(session, "r1", "modules", mri.ListModules(), MRI_S)
    assert reply.ok
    return next(m for m in reply.data.modules if m.name == "sink")


def warm(la: Launch, entry: str = "mm_sink") -> int:
    found: list[int] = []
    wait_until(lambda: bool(found.extend(p for p, ready in standbys(la.proc.pid, entry).items() if ready) or found),
               60, f"a warm standby of {entry}")
    return found[0]


def test_a_killed_module_becomes_its_standby_with_the_current_routes(robot, clients, tmp_path):
    s = clients(robot.port)
    swap = mri.call(s, "r1", "route", mri.SwapRoute(module="sink", input="datos", slot=2), MRI_S)
    assert swap.ok, swap.reason
    spare = warm(robot)
    before = sink(s)
    assert before.state == "up" and before.pid != spare
    assert "module_manager.standby" in cmdline(before.pid), "the first start too: started ahead, before the router"
    n = len(records(tmp_path))
    os.kill(before.pid, signal.SIGKILL)
    robot.wait_line("killed by signal 9; restart in 0 s")  # a first failure: no backoff
    wait_until(lambda: (m := sink(s)).state == "up" and m.pid != before.pid, 60, "the sink back up")
    after = sink(s)
    assert after.pid == spare, f"the standby became the sink; {after}; cromat launch said:\n" + "\n".join(
        robot.lines[-30:])
    assert after.restarts == 1 and after.last_exit == -signal.SIGKILL
    assert after.routes == {"datos": 2, "modo": 3}
    starts = [r for r in records(tmp_path)[n:] if r.get("event") == "start"]
    assert [{k: v for k, v in r.items() if k != "t"} for r in starts] == [
        {"module": "sink", "event": "start", "restart": 1, "routes": {"datos": 2, "modo": 3}}]
    # the mode slot's last safe-state value and the routed source's data reach the new run
    wait_until(lambda: {"module": "sink", "slot": "modo", "mode": 0} in records(tmp_path)[n:], 30, "the mode value")
    wait_until(lambda: any(r.get("slot") == "datos" for r in records(tmp_path)[n:]), 30, "data after the restart")
    assert {r["source"] for r in records(tmp_path)[n:] if r.get("slot") == "datos"} == {"src_b"}
    # a new standby for the next failure; a second kill inside the window waits for its backoff (0.2 s)
    second = warm(robot)
    assert second != spare
    os.kill(spare, signal.SIGKILL)
    robot.wait_line("killed by signal 9; restart in 0.2 s")
    wait_until(lambda: (m := sink(s)).state == "up" and m.pid == second, 60, "the second standby as the sink")
    assert sink(s).restarts == 2
    # a SIGKILLed manager takes its standbys with it (parent-death signal, as for modules)
    warm(robot)
    robot.proc.kill()
    robot.proc.wait(30)
    try:
        wait_until(lambda: group_members(robot.pgid) == [], 30, "modules and standbys gone with the manager")
    except AssertionError as exc:
        raise AssertionError(f"{exc}; still there:\n{describe(group_members(robot.pgid))}") from None


def test_a_stopped_module_has_no_standby_and_starts_cold(robot, clients):
    s = clients(robot.port)
    spare = warm(robot, "mm_source")
    stop = mri.call(s, "r1", "module", mri.ModuleCommand(module="sink", action="stop"), MRI_S)
    assert stop.ok, stop.reason
    wait_until(lambda: standbys(robot.proc.pid, "mm_sink") == {}, 30, "the sink's standby gone with it")
    start = mri.call(s, "r1", "module", mri.ModuleCommand(module="sink", action="start"), 60)
    assert start.ok and start.data.state == "up", start.reason
    assert cmdline(start.data.pid)[-2:] == ["-m", "mm_sink"], "a cold start"
    assert spare in standbys(robot.proc.pid, "mm_source"), "the sources keep theirs"
    assert robot.stop(signal.SIGTERM) == 0
    wait_until(lambda: group_members(robot.pgid) == [], 30, "every child, standbys included, gone")


def test_preload_imports_what_the_entry_imports_and_runs_nothing(tmp_path):
    pkg = tmp_path / "spare_pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "helper.py").write_text("VALUE = 42\n")
    (pkg / "__main__.py").write_text(textwrap.dedent("""
        import json
        from . import helper
        from spare_pkg.helper import VALUE
        from missing_package import anything
        open(__file__ + ".ran", "w").close()
    """))
    code = ("import sys, json; from module_manager.standby import preload; failed = preload('spare_pkg'); "
            "print(json.dumps({'failed': failed, 'helper': 'spare_pkg.helper' in sys.modules}))")
    env = child_env()
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path), str(ROOT), env.get("PYTHONPATH", "")])
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout) == {"failed": ["missing_package"], "helper": True}
    assert not (pkg / "__main__.py.ran").exists(), "the entry's body must not run before the context arrives"
    assert preload("no_such_entry_anywhere") == ["no_such_entry_anywhere"]
    with pytest.raises(ValueError):
        context_line('{"robot": "r1",\n"module": "x"}')
