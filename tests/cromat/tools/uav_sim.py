"""One simulated UAV (``cromat launch bbcs_conf/uav1_sim.toml`` on a free port) shared by a test module, and
``cromat`` subcommands run as child processes against it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "tests" / "module_manager"))
from launch_support import Launch  # noqa: E402

from bbcs.testing import child_env  # noqa: E402


def start_uav(tmp: Path) -> Launch:
    la = Launch(ROOT / "bbcs_conf" / "uav1_sim.toml", tmp)
    try:
        la.wait_line("all 6 modules up", 90)
    except BaseException:
        la.cleanup()
        raise
    return la


def cromat(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    """Run ``cromat ARGS`` to completion; stdout and stderr captured as text."""
    return subprocess.run([sys.executable, "-m", "cromat", *args], cwd=str(ROOT), env=child_env(),
                          capture_output=True, text=True, timeout=timeout)


def cromat_all(*commands: tuple[str, ...], timeout: float = 60.0) -> list[subprocess.CompletedProcess[str]]:
    """Run several ``cromat`` commands at once (most of each is a listening window), to completion, in order."""
    procs = [spawn(*args) for args in commands]
    done = []
    try:
        for args, proc in zip(commands, procs, strict=True):
            out, err = proc.communicate(timeout=timeout)
            done.append(subprocess.CompletedProcess([sys.executable, "-m", "cromat", *args], proc.returncode, out, err))
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    return done


def spawn(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "cromat", *args], cwd=str(ROOT), env=child_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
