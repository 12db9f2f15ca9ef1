"""The battery from the DSP simulator to the ground station: the simulator's ``Engine.battery_v`` goes through
the DSP process, the telemetry module (``RobotTelemetry.battery_v``), the manager and the RAL to ``cromat gcs
watch`` — the value the simulator was started with, not a default — and into the robot's fleet bid as its state
of charge (the manifest's 6S pack, ``battery_empty_v`` .. ``battery_full_v``), which the auction weighs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from bbcs.contracts.fleet import FleetTarget, FleetTask
from bbcs.session import open_session
from bbcs.testing import child_env, wait_until
from ral.fleet_gcs import FleetView
from ral.gcs.api import Gcs, session_config

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "module_manager"))
from launch_support import Launch  # noqa: E402

BATTERY_V = 23.4  # not the simulator's default (25.2); the rotor stands still on the ground, so nothing drains
EMPTY_V, FULL_V = 19.8, 25.2  # uav1_sim.toml's RAL parameters battery_empty_v, battery_full_v


def test_the_simulators_battery_reaches_the_gcs_watch(tmp_path):
    text = (ROOT / "bbcs_conf" / "uav1_sim.toml").read_text()
    sim = '"modules.dsp.sim", "--tcp", "127.0.0.1:{port:dsp}"'
    assert sim in text
    text = text.replace(sim, sim + f', "--battery", "{BATTERY_V}"')
    text = text.replace('conf = "uav1.conf"', f'conf = "{ROOT / "bbcs_conf" / "uav1.conf"}"')
    manifest = tmp_path / "uav1_battery.toml"
    manifest.write_text(text)
    la = Launch(manifest, tmp_path)
    try:
        la.wait_line("all 6 modules up", 90)
        endpoint = f"tcp/127.0.0.1:{la.port}"
        with Gcs(session_config([endpoint])) as gcs:
            wait_until(lambda: (t := gcs.state("uav1", 5.0).telemetry) is not None and t.battery_v is not None,
                       30, "a GRI state with the battery")
            assert abs(gcs.state("uav1", 5.0).telemetry.battery_v - BATTERY_V) < 1e-3
        watch = subprocess.run([sys.executable, "-m", "cromat", "gcs", "--connect", endpoint, "watch", "uav1",
                                "--count", "2"], cwd=str(ROOT), env=child_env(), capture_output=True, text=True,
                               timeout=60)
        assert watch.returncode == 0, watch.stderr
        lines = watch.stdout.splitlines()
        assert any(f"battery {BATTERY_V:.1f} V" in line for line in lines), watch.stdout
        assert all(len(line) <= 80 for line in lines)

        # the robot's fleet bid carries the state of charge of that voltage (2/3), not "unknown"
        assert f'battery_full_v = "{FULL_V}", battery_empty_v = "{EMPTY_V}"' in text
        with open_session(session_config([endpoint])) as session:
            view = FleetView(session)
            try:
                with Gcs(session_config([endpoint])) as gcs:
                    here = gcs.state("uav1", 5.0).telemetry.position
                view.post(FleetTask(id="near", targets=[FleetTarget(id="t", lat=round(here.lat + 2e-4, 4),
                                                                    lon=round(here.lon, 4), alt=here.alt + 10)]))
                bid = view.wait(lambda: next((b for st in view.states.values() for b in st.bids
                                              if b.task == "near" and b.state is not None), None), 30)
                assert bid is not None and bid.robot == "uav1", view.states
                assert abs(bid.state.battery - (BATTERY_V - EMPTY_V) / (FULL_V - EMPTY_V)) < 1e-3, bid.state
            finally:
                view.close()
    finally:
        la.stop()
        la.cleanup()
