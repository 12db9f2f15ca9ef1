"""Issue 30 case 8 on the shipped ``uav1_sim.toml``: ``failsafe_action = "retrun"`` and a misspelt ``stal_s`` in
the RAL's params. ``cromat launch --check`` fails naming each key at the manifest's file:line; ``cromat launch``
stops before anything starts with the same reasons (exit 2): no router port open, no module log, no process of
the launch left. (A module that refuses its configuration once started stops the whole launch too:
tests/module_manager/test_launch.py.)"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from bbcs.net import wait_tcp
from bbcs.testing import child_env

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_gcs_mission import sim_manifest  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "module_manager"))
from launch_support import ROOT, Launch, group_members  # noqa: E402


def misspelt(text: str) -> str:
    for old, new in (('failsafe_action = "hold"', 'failsafe_action = "retrun"'), ('stall_s = "30"', 'stal_s = "30"')):
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return text


def test_check_and_launch_name_each_bad_ral_param_at_its_line_and_start_nothing(tmp_path: Path) -> None:
    manifest, record = sim_manifest(tmp_path, edit=misspelt)
    line = next(i for i, t in enumerate(manifest.read_text().splitlines(), 1) if "stal_s" in t)
    check = subprocess.run([sys.executable, "-m", "module_manager.cli", str(manifest), "--check"], cwd=str(ROOT),
                           env=child_env(), capture_output=True, text=True, timeout=60)
    assert check.returncode == 2 and "ok" not in check.stdout, check.stdout
    for key, why in (("failsafe_action", "bad value 'retrun'"), ("stal_s", "did you mean stall_s?")):
        assert f"{manifest}:{line}: modules.ral.params.{key}: " in check.stderr and why in check.stderr, check.stderr
    assert "(one of: hold, return, land)" in check.stderr

    la = Launch(manifest, tmp_path)
    try:
        assert la.proc.wait(60) == 2
        la.reader.join(10)
        out = "\n".join(la.lines)
        assert f"{manifest}:{line}: modules.ral.params.failsafe_action: bad value 'retrun'" in out, out
        assert "modules.ral.params.stal_s" in out and "all 6 modules up" not in out
        assert group_members(la.pgid) == [], "a process of the launch is running"
        assert not la.log_dir.exists() and not record.exists(), "something was started"
        assert not wait_tcp("127.0.0.1", la.port, 0.5), "the robot router listens"
    finally:
        la.cleanup()


def test_check_and_launch_name_a_misspelt_vision_param_at_its_line_and_start_nothing(tmp_path: Path) -> None:
    """The vision module checks its params like the RAL: a misspelt ``target_east`` and a rate out of range are
    named at the manifest's line (the nearest known name given), and the robot does not come up half-started."""
    def edit(text: str) -> str:
        old = 'rate = "10", ground_alt = "12", target_east = "30"'
        assert text.count(old) == 1, old
        return text.replace(old, 'rate = "500", ground_alt = "12", target_est = "30"')

    manifest, record = sim_manifest(tmp_path, edit=edit)
    line = next(i for i, t in enumerate(manifest.read_text().splitlines(), 1) if "target_est" in t)
    check = subprocess.run([sys.executable, "-m", "module_manager.cli", str(manifest), "--check"], cwd=str(ROOT),
                           env=child_env(), capture_output=True, text=True, timeout=60)
    assert check.returncode == 2 and "ok" not in check.stdout, check.stdout
    assert (f"{manifest}:{line}: modules.vision.params.target_est: unknown vision parameter "
            "(did you mean target_east?") in check.stderr, check.stderr
    assert f"{manifest}:{line}: modules.vision.params.rate: bad value '500'" in check.stderr, check.stderr

    la = Launch(manifest, tmp_path)
    try:
        assert la.proc.wait(60) == 2
        la.reader.join(10)
        out = "\n".join(la.lines)
        assert f"{manifest}:{line}: modules.vision.params.target_est: unknown vision parameter" in out, out
        assert group_members(la.pgid) == [], "a process of the launch is running"
        assert not la.log_dir.exists() and not record.exists(), "something was started"
        assert not wait_tcp("127.0.0.1", la.port, 0.5), "the robot router listens"
    finally:
        la.cleanup()
