"""examples/plain_client.py (zenoh + msgpack only) against the launched simulated UAV: it reads the GRI state
(with its self-describing encoding and the robot's telemetry inside), holds a ground-station link that the robot
reports up, its pan & tilt task is accepted, the simulated camera mount reaches the angles and the task is
listed as running with its typed params; the out-of-range one is refused with the reason."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from bbcs.testing import child_env

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "module_manager"))
from launch_support import ROOT, Launch  # noqa: E402


def test_plain_client_reads_state_and_moves_the_camera(tmp_path):
    la = Launch(ROOT / "bbcs_conf" / "uav1_sim.toml", tmp_path)
    try:
        la.wait_line("all 6 modules up", 120)
        env = child_env()
        env.pop("PYTHONPATH", None)  # the client needs no project code: only zenoh and msgpack
        out = subprocess.run([sys.executable, str(ROOT / "examples" / "plain_client.py"), "--connect",
                              f"tcp/127.0.0.1:{la.port}", "--robot", "uav1", "--link", "plain"], cwd=tmp_path, env=env,
                             capture_output=True, text=True, timeout=180)
        assert out.returncode == 0, out.stdout + out.stderr
        assert "plain_client: state encoding application/msgpack;bbcs.contracts.gri:GriState" in out.stdout
        lat = float(re.search(r"plain_client: uav1 \(uav\) at lat (\S+)", out.stdout).group(1))
        assert 37.0 < lat < 38.0  # the simulated aircraft's home, near Seville
        assert "'pan_tilt'" in re.search(r"task kinds (.*)", out.stdout).group(1)
        assert "plain_client: link up as ground station plain" in out.stdout
        assert "pan_tilt reply {'accepted': True" in out.stdout
        pan, tilt = map(float, re.search(r"camera at pan (\S+) tilt (\S+)", out.stdout).groups())
        assert abs(pan - 30.0) < 2.0 and abs(tilt + 20.0) < 2.0
        assert re.search(r"task \d+ in the state: running params \{'type': 'pan_tilt', 'pan': 30.0, 'tilt': -20.0\}",
                         out.stdout), out.stdout
        assert "pan 500 reply {'accepted': False, 'reason': 'invalid or unknown task:" in out.stdout
        assert "`$.pan`" in out.stdout
    finally:
        la.stop()
        la.cleanup()
