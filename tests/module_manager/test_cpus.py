"""``cpus`` in a manifest: a module runs, every thread of it (Zenoh's included), on the processors it names; so do
its warm standby and the process that replaces it after a SIGKILL; a module without ``cpus`` keeps the manager's
own; a plain process and the router (``[bus] cpus``) are placed the same way."""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

import pytest

from bbcs.contracts import mri
from bbcs.testing import wait_until

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch_support import Launch, group_members, standbys, write_manifest  # noqa: E402

MRI_S = 20.0
ALLOWED = os.sched_getaffinity(0)
PINNED = max(ALLOWED)


def thread_cpus(pid: int) -> dict[int, str]:
    """Thread id → its ``Cpus_allowed_list`` (``/proc/PID/task/TID/status``), for every thread of ``pid``."""
    out = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        for line in (task / "status").read_text().splitlines():
            if line.startswith("Cpus_allowed_list:"):
                out[int(task.name)] = line.split(":", 1)[1].strip()
    return out


def kernel_list(cpus: set[int]) -> str:
    return ",".join(str(c) for c in sorted(cpus)) if len(cpus) == 1 else f"{min(cpus)}-{max(cpus)}"


def pinned_manifest(text: str) -> str:
    text = text.replace("period_s = 30.0", "period_s = 30.0\nstandby = true")
    text = text.replace("start_timeout_s = 20.0", "start_timeout_s = 60.0")
    text = text.replace('task_types = ["perception"]', f'task_types = ["perception"]\ncpus = [{PINNED}]')
    text = text.replace('listen = ["tcp/127.0.0.1:{port:router}"]',
                        f'listen = ["tcp/127.0.0.1:{{port:router}}"]\ncpus = [{PINNED}]')
    return text + f'\n[processes.idle]\ncommand = ["sleep", "600"]\ncpus = [{PINNED}]\n'


@pytest.fixture
def robot(tmp_path):
    if len(ALLOWED) < 2:
        pytest.skip("one processor: a module's placement cannot differ from the manager's")
    la = Launch(write_manifest(tmp_path, edit=pinned_manifest), tmp_path)
    try:
        la.wait_line("all 3 modules up")
        yield la
    finally:
        la.cleanup()


def status(session, name: str) -> mri.ModuleStatus:
    reply = mri.call(session, "r1", "modules", mri.ListModules(), MRI_S)
    assert reply.ok
    return next(m for m in reply.data.modules if m.name == name)


def test_a_module_and_its_replacements_run_on_the_processors_it_names(robot, clients):
    s = clients(robot.port)
    sink, source = status(s, "sink"), status(s, "src_a")
    threads = thread_cpus(sink.pid)
    assert len(threads) > 3, f"the sink runs Zenoh's threads too: {threads}"
    assert set(threads.values()) == {str(PINNED)}, threads
    assert set(thread_cpus(source.pid).values()) == {kernel_list(ALLOWED)}, "src_a names no cpus: left alone"
    assert any(f"sink        starting, pid {sink.pid} on cpus {PINNED}" in line for line in robot.lines)
    router = next(p for p in group_members(robot.pgid) if b"bbcs.router" in Path(f"/proc/{p}/cmdline").read_bytes())
    assert set(thread_cpus(router).values()) == {str(PINNED)}, "[bus] cpus places the router"
    assert any(line.startswith("  router      listening on") and f"on cpus {PINNED}" in line for line in robot.lines)
    idle = next(line for line in robot.lines if line.strip().startswith("idle") and "ready" in line)
    idle_pid = int(idle.split("pid ")[1].split()[0])
    assert set(thread_cpus(idle_pid).values()) == {str(PINNED)}, idle

    found: list[int] = []
    wait_until(lambda: bool(found.extend(p for p, ok in standbys(robot.proc.pid, "mm_sink").items() if ok) or found),
               60, "a warm standby of the sink")
    assert set(thread_cpus(found[0]).values()) == {str(PINNED)}, "the standby is placed before it is needed"
    os.kill(sink.pid, signal.SIGKILL)
    wait_until(lambda: (m := status(s, "sink")).state == "up" and m.pid != sink.pid, 60, "the sink back up")
    again = status(s, "sink")
    assert again.pid == found[0]
    threads = thread_cpus(again.pid)
    assert len(threads) > 3 and set(threads.values()) == {str(PINNED)}, threads
