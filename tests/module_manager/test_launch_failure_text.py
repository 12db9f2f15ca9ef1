"""A launch whose router does not listen in time says why in words, never "(exit None)" (issue 34 item 8)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from bbcs.testing import child_env, free_port

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch_support import ROOT, write_manifest  # noqa: E402


def test_a_router_still_starting_is_said_so(tmp_path: Path) -> None:
    port = free_port()
    manifest = write_manifest(tmp_path, edit=lambda t: t.replace(
        'listen = ["tcp/127.0.0.1:{port:router}"]', f'listen = ["tcp/127.0.0.1:{port}"]\nready_timeout_s = 0.001'))
    r = subprocess.run([sys.executable, "-m", "cromat", "launch", str(manifest)], cwd=str(ROOT), env=child_env(),
                       capture_output=True, text=True, timeout=60)
    text = r.stdout + r.stderr
    assert r.returncode != 0, text
    assert f"the router did not listen on 127.0.0.1:{port} within 0.001 s (still starting" in text, text
    assert "exit None" not in text


def test_a_process_still_running_but_not_ready_is_said_so(tmp_path: Path) -> None:
    manifest = write_manifest(tmp_path, edit=lambda t: t + (
        '\n[processes.sleeper]\ncommand = ["{python}", "-c", "import time; time.sleep(60)"]\n'
        'ready = { kind = "stdout", pattern = "never said", timeout_s = 0.5 }\n'))
    r = subprocess.run([sys.executable, "-m", "cromat", "launch", str(manifest), "--listen",
                        f"tcp/127.0.0.1:{free_port()}"], cwd=str(ROOT), env=child_env(), capture_output=True,
                       text=True, timeout=90)
    text = r.stdout + r.stderr
    assert r.returncode != 0, text
    assert "not ready within 0.5 s (ready: stdout; still running, not ready yet)" in text, text
    assert "exit None" not in text
