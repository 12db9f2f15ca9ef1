"""The sim UAV manifest (bbcs_conf/uav1_sim.toml) comes up with every module alive, robot telemetry reaches the
robot state, and SIGTERM leaves no process behind."""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path

import msgspec

from bbcs import keys
from bbcs.contracts import mri
from bbcs.session import local_client, open_session
from bbcs.testing import wait_until

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch_support import ROOT, Launch, group_members  # noqa: E402


def test_sim_uav_comes_up_and_stops_clean(tmp_path):
    la = Launch(ROOT / "bbcs_conf" / "uav1_sim.toml", tmp_path)
    session = None
    sub = None
    try:
        la.wait_line("all 6 modules up", 90)
        session = open_session(local_client(la.port))
        reply = mri.call(session, "uav1", "modules", mri.ListModules(), 20.0)
        assert reply.ok
        assert {m.name: m.state for m in reply.data.modules} == {
            "dsp": "up", "telemetry": "up", "pan_tilt": "up", "path_follower": "up", "vision": "up", "ral": "up"}
        states: list[mri.RobotState] = []
        got = threading.Event()
        decode = msgspec.msgpack.Decoder(mri.RobotState).decode

        def on_state(sample) -> None:
            state = decode(sample.payload.to_bytes())
            states.append(state)
            if state.telemetry is not None:
                got.set()

        sub = session.declare_subscriber(keys.manager_key("uav1", "state"), on_state)
        assert got.wait(20), "robot telemetry from the DSP simulator folded into the robot state"
        assert states[-1].kind == "uav" and states[-1].telemetry.position is not None
        assert la.stop(signal.SIGTERM) == 0
        wait_until(lambda: group_members(la.pgid) == [], 30, "no process of the launch left")
    finally:
        if sub is not None:
            sub.undeclare()
        if session is not None:
            session.close()
        la.cleanup()
