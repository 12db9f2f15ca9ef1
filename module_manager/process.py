"""Child processes of the manager: spawned so that none outlives it, stopped TERM-then-KILL.

A child may also get a scheduling priority from the manifest (``nice``, ``realtime``): set between fork and exec
like its processors, so every thread it starts inherits it. The OS may refuse it (a negative nice or a real-time
policy needs CAP_SYS_NICE or a large enough RLIMIT_NICE / RLIMIT_RTPRIO): the child then runs at the priority it
inherited, says so on its stderr (its log), and :attr:`Child.priority_refused` says what was refused and why, which
the launch prints. A refusal never stops the launch: the priority is a latency aid under load, not a condition for
flying, and a laptop without those rights must still run the shipped simulations.

Every child stays in the manager's process group (Ctrl+C in a terminal reaches all of them) and asks the kernel
for SIGTERM when its parent dies (``prctl(PR_SET_PDEATHSIG)``), so a SIGKILLed manager leaves no orphan.
The parent-death signal fires when the *thread* that forked the child ends: the manager spawns from its main
thread only.
"""

from __future__ import annotations

import ctypes
import os
import resource
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO

PR_SET_PDEATHSIG = 1
CPUS_REFUSED = 126
"""Exit status of a child that could not be placed on its ``cpus`` (said on its stderr, so in its log)."""

try:
    _libc: ctypes.CDLL | None = ctypes.CDLL(None, use_errno=True)
except OSError:  # not Linux/glibc: no parent-death signal, the process group still covers Ctrl+C
    _libc = None


@dataclass(frozen=True)
class Priority:
    """A child's scheduling priority (the manifest's ``nice`` and ``realtime``): None leaves it as inherited."""

    nice: int | None = None
    """-20 (first) to 19 (last): the CFS weight of every thread of the child."""
    realtime: int | None = None
    """1-99: SCHED_RR at this priority, ahead of every normal process (the kernel still keeps 5 % of each second
    for the rest, ``sched_rt_runtime_us``)."""

    def __bool__(self) -> bool:
        return self.nice is not None or self.realtime is not None

    def describe(self) -> str:
        return ", ".join(([f"nice {self.nice}"] if self.nice is not None else [])
                         + ([f"real-time {self.realtime}"] if self.realtime is not None else []))


def _apply_priority(priority: Priority) -> None:
    """In the child, before exec: set what it can of ``priority``; a refusal is said on stderr, never fatal."""
    if priority.nice is not None:
        try:
            os.setpriority(os.PRIO_PROCESS, 0, priority.nice)
        except OSError as exc:
            os.write(2, f"cromat: nice {priority.nice} refused ({exc.strerror}): running at the nice inherited\n"
                     .encode())
    if priority.realtime is not None:
        try:
            os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(priority.realtime))
        except OSError as exc:
            os.write(2, f"cromat: real-time priority {priority.realtime} refused ({exc.strerror}): running under "
                        f"the normal policy\n".encode())


def priority_refused(pid: int, priority: Priority) -> str | None:
    """What of ``priority`` process ``pid`` did not get, and why (None: it got all of it, or it is gone)."""
    out = []
    try:
        if priority.nice is not None and (got := os.getpriority(os.PRIO_PROCESS, pid)) != priority.nice:
            limit = resource.getrlimit(resource.RLIMIT_NICE)[0]
            out.append(f"nice {priority.nice} refused by the OS (it runs at nice {got}): going below the nice it "
                       f"inherits needs CAP_SYS_NICE or RLIMIT_NICE of {20 - priority.nice}; this launch's "
                       f"RLIMIT_NICE is {'unlimited' if limit == resource.RLIM_INFINITY else limit}")
        if priority.realtime is not None and os.sched_getscheduler(pid) != os.SCHED_RR:
            limit = resource.getrlimit(resource.RLIMIT_RTPRIO)[0]
            out.append(f"real-time priority {priority.realtime} refused by the OS (it runs under the normal "
                       f"policy): it needs CAP_SYS_NICE or RLIMIT_RTPRIO of {priority.realtime}; this launch's "
                       f"RLIMIT_RTPRIO is {'unlimited' if limit == resource.RLIM_INFINITY else limit}")
    except (ProcessLookupError, PermissionError):
        return None
    return "; ".join(out) or None


def _child_setup(parent: int, cpus: frozenset[int] | None = None, priority: Priority | None = None) -> None:
    """Runs in the child between fork and exec: die with the parent; run on ``cpus`` only (the manifest's
    ``cpus``). The affinity is set before exec, so every thread the program starts later (Zenoh's included)
    inherits it."""
    if cpus:
        try:
            os.sched_setaffinity(0, cpus)
        except OSError as exc:  # the processors went away since the manifest was checked (a cpuset changed)
            os.write(2, f"cannot run on cpus {sorted(cpus)}: {exc}\n".encode())
            os._exit(CPUS_REFUSED)
    if priority:
        _apply_priority(priority)
    if _libc is not None:
        _libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)


class Child:
    """One started process, its output handling and how it ended."""

    def __init__(self, name: str, argv: list[str], env: dict[str, str], cwd: str | None = None,
                 log_dir: Path | None = None, watch_stdout: bool = False, stdin_pipe: bool = False,
                 echo: Callable[[str], None] | None = None, cpus: frozenset[int] | None = None,
                 priority: Priority | None = None) -> None:
        """``echo``: called with every stdout line (``watch_stdout``), besides the log: what the launch must show.
        ``cpus``: the processors the child (all its threads) may run on; None: the manager's own.
        ``priority``: its scheduling priority (module docstring); what the OS refused is in ``priority_refused``."""
        self.name = name
        self._echo = echo
        self.argv = argv
        self._log: IO[bytes] | None = None
        out: int | IO[bytes] | None = None
        if log_dir is not None:
            log_dir.mkdir(parents=True, exist_ok=True)
            self._log = (log_dir / f"{name}.log").open("ab")
            out = self._log
        parent = os.getpid()
        self.first_lines: list[str] = []
        self._line_seen = threading.Condition()
        stdin = subprocess.PIPE if stdin_pipe else subprocess.DEVNULL
        self.proc = subprocess.Popen(argv, env=env, cwd=cwd, stdin=stdin,
                                     stdout=subprocess.PIPE if watch_stdout else out,
                                     stderr=out, preexec_fn=lambda: _child_setup(parent, cpus, priority))
        self.pid = self.proc.pid
        self.priority_refused = priority_refused(self.pid, priority) if priority else None
        """What of ``priority`` the OS refused, and why (None: all of it was set, or none was asked)."""
        self.started = time.monotonic()
        self.pidfd: int | None = None
        """Readable once the process exits (Linux ``pidfd_open``): the manager sleeps on it to reap at once."""
        try:
            self.pidfd = os.pidfd_open(self.pid)
        except (AttributeError, OSError):  # not Linux ≥ 5.3: the manager's periodic poll still reaps it
            self.pidfd = None
        self._reader: threading.Thread | None = None
        if watch_stdout:
            self._reader = threading.Thread(target=self._pump, name=f"stdout-{name}", daemon=True)
            self._reader.start()

    def _pump(self) -> None:
        """Keep stdout flowing (to the log or ours) and remember the first lines for readiness checks."""
        assert self.proc.stdout is not None
        for raw in self.proc.stdout:
            line = raw.decode(errors="replace").rstrip("\n")
            with self._line_seen:
                if len(self.first_lines) < 100:
                    self.first_lines.append(line)
                self._line_seen.notify_all()
            if self._log is not None:
                self._log.write(raw)
                self._log.flush()
            if self._echo is not None:
                self._echo(line)
        with self._line_seen:
            self._line_seen.notify_all()

    def wait_line(self, pattern: str, timeout_s: float) -> bool:
        """True once a stdout line containing ``pattern`` (any line if empty) was printed."""
        end = time.monotonic() + timeout_s
        with self._line_seen:
            while True:
                if any(pattern in line for line in self.first_lines):
                    return True
                left = end - time.monotonic()
                if left <= 0 or self.proc.poll() is not None:
                    return any(pattern in line for line in self.first_lines)
                self._line_seen.wait(min(left, 0.1))

    def poll(self) -> int | None:
        return self.proc.poll()

    def send_and_close_stdin(self, data: bytes) -> None:
        """Write ``data`` to the child's stdin pipe (``stdin_pipe``) and close it; OSError if the child is gone."""
        assert self.proc.stdin is not None
        try:
            if data:
                self.proc.stdin.write(data)
                self.proc.stdin.flush()
        finally:
            try:
                self.proc.stdin.close()
            except OSError:
                pass

    def signal(self, sig: int) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.send_signal(sig)
            except ProcessLookupError:
                pass

    def close(self) -> None:
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            try:
                self.proc.stdin.close()
            except OSError:
                pass
        if self.pidfd is not None:
            os.close(self.pidfd)
            self.pidfd = None
        if self._reader is not None:
            self._reader.join(1.0)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        if self._log is not None:
            self._log.close()


def stop_children(children: list[Child], grace_s: float, on_stopped: Callable[[Child, int], None] | None = None
                  ) -> None:
    """SIGTERM each (in the order given), wait up to ``grace_s`` for all, SIGKILL the rest, reap everything."""
    for child in children:
        child.signal(signal.SIGTERM)
    end = time.monotonic() + grace_s
    pending = [c for c in children]
    while pending and time.monotonic() < end:
        pending = [c for c in pending if c.poll() is None]
        if pending:
            time.sleep(0.02)
    for child in pending:
        child.signal(signal.SIGKILL)
    for child in children:
        code = child.proc.wait()
        if on_stopped is not None:
            on_stopped(child, code)
        child.close()
