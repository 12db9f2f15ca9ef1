"""Process priority from the manifest (issue 32): ``nice`` and ``realtime`` next to ``cpus``.

A child gets its nice value (every thread of it, Zenoh's included) and the real-time policy where the OS allows;
where the OS refuses (a user without CAP_SYS_NICE asking a negative nice), the child runs all the same at the nice
it inherited, says so in its log, and the launch is told what was refused and why. Out-of-range values are
manifest errors at file:line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from module_manager.manifest import ManifestError, load_manifest
from module_manager.process import Child, Priority, stop_children

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch_support import ROOT, Launch, group_members, write_manifest  # noqa: E402

THREADED = ("import threading, time; threading.Thread(target=time.sleep, args=(30,), daemon=True).start(); "
            "print('up', flush=True); time.sleep(30)")


def thread_nices(pid: int) -> dict[int, int]:
    """Thread id → nice (field 19 of ``/proc/PID/task/TID/stat``) for every thread of ``pid``."""
    out = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        out[int(task.name)] = int(fields[16])
    return out


def start(tmp_path: Path, priority: Priority) -> Child:
    child = Child("probe", [sys.executable, "-c", THREADED], dict(os.environ), log_dir=tmp_path, watch_stdout=True,
                  priority=priority)
    assert child.wait_line("up", 30), "the probe never started"
    return child


def test_every_thread_of_the_child_gets_the_nice_value(tmp_path: Path) -> None:
    child = start(tmp_path, Priority(nice=7))
    try:
        nices = thread_nices(child.pid)
        assert len(nices) >= 2 and set(nices.values()) == {7}, nices
        assert child.priority_refused is None
    finally:
        stop_children([child], 2.0)


def _may_set_realtime() -> bool:
    probe = subprocess.run([sys.executable, "-c", "import os; os.sched_setscheduler(0, os.SCHED_RR, "
                                                  "os.sched_param(1))"], capture_output=True)
    return probe.returncode == 0


def test_the_real_time_policy_where_the_os_allows_it_else_a_reason(tmp_path: Path) -> None:
    child = start(tmp_path, Priority(realtime=1))
    try:
        if _may_set_realtime():
            assert os.sched_getscheduler(child.pid) == os.SCHED_RR
            assert child.priority_refused is None
        else:
            assert os.sched_getscheduler(child.pid) == os.SCHED_OTHER
            assert "real-time priority 1 refused by the OS" in (child.priority_refused or "")
    finally:
        stop_children([child], 2.0)


REFUSED = """
import json, os, sys
from module_manager.process import Child, Priority, stop_children
if os.geteuid() == 0:  # a user without CAP_SYS_NICE (everything imported first: some of the library is root's)
    os.setgroups([]); os.setgid(65534); os.setuid(65534)
child = Child("probe", ["/bin/sh", "-c", "echo up; exec sleep 30"],
              dict(os.environ), log_dir=None, watch_stdout=True, priority=Priority(nice=-5))
up = child.wait_line("up", 30)
nice = os.getpriority(os.PRIO_PROCESS, child.pid)
refused = child.priority_refused
stop_children([child], 2.0)
print(json.dumps({"up": up, "nice": nice, "refused": refused, "mine": os.getpriority(os.PRIO_PROCESS, 0)}))
"""


def test_a_refused_negative_nice_is_said_with_its_reason_and_the_child_runs(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-c", REFUSED], cwd=str(ROOT), capture_output=True, text=True, timeout=60,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["up"], "the child must run all the same"
    assert got["nice"] == got["mine"], "it keeps the nice it inherited"
    assert got["refused"].startswith(f"nice -5 refused by the OS (it runs at nice {got['mine']}): ")
    assert "CAP_SYS_NICE or RLIMIT_NICE of 25" in got["refused"]
    assert "cromat: nice -5 refused (Permission denied)" in proc.stderr or "Operation not permitted" in proc.stderr


@pytest.mark.parametrize("line,key", [("nice = -21", "modules.sink.nice"), ("nice = 20", "modules.sink.nice"),
                                      ("realtime = 0", "modules.sink.realtime"),
                                      ("realtime = 100", "modules.sink.realtime")])
def test_out_of_range_priorities_are_manifest_errors(tmp_path: Path, line: str, key: str) -> None:
    path = write_manifest(tmp_path, edit=lambda t: t.replace('task_types = ["perception"]',
                                                               f'task_types = ["perception"]\n{line}'))
    with pytest.raises(ManifestError) as info:
        load_manifest(path)
    assert info.value.key == key


def test_a_launched_module_and_process_run_at_their_manifest_nice(tmp_path: Path) -> None:
    def edit(text: str) -> str:
        text = text.replace('task_types = ["perception"]', 'task_types = ["perception"]\nnice = 4')
        assert 'listen = ["tcp/127.0.0.1:{port:router}"]\n' in text
        text = text.replace('listen = ["tcp/127.0.0.1:{port:router}"]\n',
                            'listen = ["tcp/127.0.0.1:{port:router}"]\nnice = 2\n')  # the router's
        return text + '\n[processes.idle]\ncommand = ["sleep", "600"]\nnice = 6\n'

    la = Launch(write_manifest(tmp_path, edit=edit), tmp_path)
    try:
        la.wait_line("all 3 modules up")
        sink = next(line for line in la.lines if line.strip().startswith("sink") and "starting, pid" in line)
        idle = next(line for line in la.lines if line.strip().startswith("idle") and "ready" in line)
        sink_pid = int(sink.split("pid ")[1].split()[0].rstrip(","))
        idle_pid = int(idle.split("pid ")[1].split()[0].rstrip(","))
        nices = thread_nices(sink_pid)
        assert len(nices) > 3 and set(nices.values()) == {4}, nices
        assert set(thread_nices(idle_pid).values()) == {6}
        routers = [pid for pid in group_members(la.pgid)
                   if b"bbcs.router" in Path(f"/proc/{pid}/cmdline").read_bytes()]
        assert len(routers) == 1 and set(thread_nices(routers[0]).values()) == {2}
        mine = os.getpriority(os.PRIO_PROCESS, 0)
        other = next(line for line in la.lines if line.strip().startswith("src_a") and "starting, pid" in line)
        assert set(thread_nices(int(other.split("pid ")[1].split()[0].rstrip(","))).values()) == {mine}
        assert not any("refused by the OS" in line for line in la.lines)
    finally:
        la.cleanup()


def test_a_lockstep_launch_leaves_raised_priorities_out_and_keeps_lowered_ones() -> None:
    """In lockstep the barrier makes the flight independent of load: a raised priority would only take the
    processors from the rest of the machine (a uQuad stack at nice -10 at --speed max starved a DSP simulator)."""
    from types import SimpleNamespace

    from module_manager.manager import _priority, raised_priorities

    raised = SimpleNamespace(nice=-10, realtime=None)
    rt = SimpleNamespace(nice=None, realtime=10)
    lowered = SimpleNamespace(nice=5, realtime=None)
    assert _priority(raised) == Priority(nice=-10) and _priority(rt) == Priority(realtime=10)
    assert _priority(raised, lockstep_on=True) is None and _priority(rt, lockstep_on=True) is None
    assert _priority(lowered, lockstep_on=True) == Priority(nice=5)
    assert raised_priorities({"sim": raised, "log": lowered, "ctl": rt}) == ["ctl", "sim"]
