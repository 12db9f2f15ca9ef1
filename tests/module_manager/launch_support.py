"""Helpers of the launch tests: write a test manifest, run ``cromat launch`` in its own process group, read
its output, find leftover processes by process group in /proc."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from bbcs.testing import child_env, free_port

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]


def write_manifest(tmp_path: Path, *, edit=None, name: str = "robot.toml") -> Path:
    """The probe-robot manifest with absolute paths and the sink recording into ``tmp_path``."""
    text = (HERE / "probe_robot.toml").read_text()
    text = text.replace('pythonpath = ["."]', f'pythonpath = ["{HERE}"]')
    text = text.replace('conf = "probe_robot.conf"', f'conf = "{HERE / "probe_robot.conf"}"')
    if edit is not None:
        text = edit(text)
    path = tmp_path / name
    path.write_text(text)
    return path


def group_members(pgid: int) -> list[int]:
    """Pids of every live (non-zombie) process whose process group is ``pgid``."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat.rpartition(")")[2].split()
        if fields[0] != "Z" and int(fields[2]) == pgid:
            out.append(int(entry.name))
    return out


class Launch:
    """``python -m module_manager.cli MANIFEST`` as a session leader, its stdout collected line by line."""

    def __init__(self, manifest: Path, tmp_path: Path, *extra: str, port: int | None = None) -> None:
        self.port = port or free_port()
        self.log_dir = tmp_path / "logs"
        """Each child's stdout/stderr, ``<name>.log`` (``cromat launch --log-dir``)."""
        self.lines: list[str] = []
        self.cond = threading.Condition()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "module_manager.cli", str(manifest), "--listen", f"tcp/127.0.0.1:{self.port}",
             "--log-dir", str(self.log_dir), *extra],
            cwd=str(ROOT), env=child_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            start_new_session=True)
        self.pgid = self.proc.pid
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self.cond:
                self.lines.append(line.rstrip("\n"))
                self.cond.notify_all()

    def wait_line(self, text: str, timeout_s: float = 60.0) -> str:
        end = time.monotonic() + timeout_s
        with self.cond:
            while True:
                for line in self.lines:
                    if text in line:
                        return line
                left = end - time.monotonic()
                if left <= 0 or (self.proc.poll() is not None and not self.reader.is_alive()):
                    raise AssertionError(f"no line with {text!r} from cromat launch; output:\n" + "\n".join(self.lines))
                self.cond.wait(min(left, 0.2))

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 30.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout_s)
        finally:
            self.reader.join(5)

    def cleanup(self) -> None:
        """Whatever happened, leave nothing of this launch behind."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)
        for pid in group_members(self.pgid):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if self.proc.stdout is not None:
            self.proc.stdout.close()


def standbys(manager_pid: int, entry: str) -> dict[int, bool]:
    """The manager's standby processes of ``entry`` (module_manager/standby.py): pid → warm (its imports done,
    blocked reading its context: ``/proc/PID/syscall`` shows ``read`` on fd 0)."""
    found: dict[int, bool] = {}
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            argv = (proc / "cmdline").read_bytes().split(b"\0")
            fields = (proc / "stat").read_text().rpartition(")")[2].split()
            if int(fields[1]) != manager_pid or fields[0] == "Z" or b"module_manager.standby" not in argv \
                    or entry.encode() not in argv:
                continue
            call = (proc / "syscall").read_text().split()
        except (OSError, ValueError, IndexError):
            continue
        found[int(proc.name)] = call[:2] == ["0", "0x0"]
    return found


def describe(pids: list[int]) -> str:
    """What a test that expected these processes gone prints: each one's command line, state and parent."""
    out = []
    for pid in pids:
        try:
            status = dict(line.split(":\t", 1) for line in (Path("/proc") / str(pid) / "status").read_text()
                          .splitlines() if ":\t" in line)
            out.append(f"{pid} ({status.get('State', '?').strip()}, parent {status.get('PPid', '?').strip()}, "
                       f"{status.get('Threads', '?').strip()} threads): {' '.join(cmdline(pid))}")
        except OSError:
            out.append(f"{pid}: gone")
    return "\n".join(out)


def cmdline(pid: int) -> list[str]:
    return [a.decode() for a in (Path("/proc") / str(pid) / "cmdline").read_bytes().split(b"\0") if a]
