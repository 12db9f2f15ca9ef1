"""``cromat fleet`` as the system tests run it: its own session leader, every output line kept, stopped with
everything it started (also on failure)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from bbcs.testing import child_env, wait_until

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "module_manager"))
from launch_support import ROOT, group_members  # noqa: E402

FLEET_PACE = 4.0
"""``--speed`` of the suite's fleets in lockstep: paced, not "max". At "max" a fleet takes every free processor while
its test waits on the wall clock (a CLI run, a ground station's reply), which the other test workers need. Paced at
4x (the free-running fleets' time scale) a two-robot fleet costs about half a processor however long its test
waits, and still flies the same flight."""


class FleetRun:
    """``python -m module_manager.fleet MANIFEST --run-dir RUN``; ``lines`` holds its output so far."""

    def __init__(self, manifest: Path, run: Path) -> None:
        self.run = run
        self.lines: list[str] = []
        self.proc = subprocess.Popen([sys.executable, "-m", "module_manager.fleet", str(manifest), "--run-dir",
                                      str(run)], cwd=str(ROOT), env=child_env(), stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, start_new_session=True)
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())

    def wait_line(self, match: Callable[[str], object], timeout_s: float, what: str) -> str:
        """The first output line ``match`` accepts, waiting for it (fails, showing the last lines, if the launcher
        exits or the deadline passes first)."""
        try:
            wait_until(lambda: any(match(x) for x in self.lines) or self.proc.poll() is not None, timeout_s, what)
        except AssertionError as exc:
            up = [x for x in self.lines if "modules up" in x]
            raise AssertionError(f"{exc}; up so far: {up}; the last lines:\n" + "\n".join(self.lines[-30:])) from None
        found = next((x for x in self.lines if match(x)), None)
        assert found is not None, f"cromat fleet exited ({self.proc.poll()}) before {what}:\n" + "\n".join(
            self.lines[-40:])
        return found

    def hub_port(self, robots: int, timeout_s: float) -> int:
        """Wait for "fleet: all N robots up, meshed on tcp/…" and return the hub router's port."""
        up = self.wait_line(lambda x: x.startswith(f"fleet: all {robots} robots up"), timeout_s,
                            f"the {robots} robots up")
        found = re.search(r"meshed on tcp/127\.0\.0\.1:(\d+)", up)
        assert found is not None, up
        return int(found.group(1))

    def stop(self, grace_s: float = 120.0) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(grace_s)
        finally:
            for pid in group_members(self.proc.pid):
                os.kill(pid, signal.SIGKILL)


@contextmanager
def fleet_run(manifest: Path, run: Path) -> Iterator[FleetRun]:
    fleet = FleetRun(manifest, run)
    try:
        yield fleet
    finally:
        fleet.stop()
