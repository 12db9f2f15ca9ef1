"""End to end: a module whose handler is stuck stops its heartbeat (it comes from the event loop), and the
manager's watchdog kills and restarts it while the other modules keep running."""

from __future__ import annotations

import json
import signal
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "module_manager"))

from launch_support import Launch, write_manifest  # noqa: E402

from bbcs.contracts import mri  # noqa: E402
from bbcs.testing import wait_until  # noqa: E402


def add_stuck(text: str) -> str:
    text = text.replace("pythonpath = [", f'pythonpath = ["{HERE}", ', 1)
    return text + """
[modules.stuck]
entry = "stuck_module"
class = "stuck_module:Stuck"
watchdog_s = 2.0
backoff_s = 0.05
"""


def test_a_stuck_handler_is_killed_by_the_watchdog_and_restarted(tmp_path, clients) -> None:
    la = Launch(write_manifest(tmp_path, edit=add_stuck), tmp_path)
    try:
        la.wait_line("all 4 modules up", 90)
        s = clients(la.port)

        def status() -> dict[str, mri.ModuleStatus]:
            reply = mri.call(s, "r1", "modules", mri.ListModules(), 20.0)
            assert reply.ok and isinstance(reply.data, mri.ModuleList)
            return {m.name: m for m in reply.data.modules}

        wait_until(lambda: status()["stuck"].restarts >= 1, 60, "the watchdog to restart the stuck module")
        st = status()
        # the watchdog's kill is the only SIGKILL here (its reason is replaced by the exit's once it is reaped)
        assert st["stuck"].last_exit == -signal.SIGKILL, st["stuck"]
        assert all(m.restarts == 0 for n, m in st.items() if n != "stuck"), st
    finally:
        la.cleanup()


def test_a_launched_robot_describes_itself_on_the_wire(tmp_path, clients) -> None:
    """Wildcard schema query over the real modules of a launched robot: one reply per module, on its own key;
    the manager answers its @-keys' schemas; MRI replies carry msgpack with their type's name."""
    la = Launch(write_manifest(tmp_path), tmp_path)
    try:
        la.wait_line("all 3 modules up", 90)
        s = clients(la.port)
        replies = [r.ok for r in s.get("cromat/r1/*/@schema", timeout=20) if r.ok is not None]
        expected = [f"cromat/r1/{m}/@schema" for m in ("sink", "src_a", "src_b")]
        assert sorted(str(r.key_expr) for r in replies) == expected
        assert {str(r.encoding) for r in replies} == {"application/json;json-schema"}
        manager = [r.ok for r in s.get("cromat/r1/@manager/@schema", timeout=20) if r.ok is not None]
        assert len(manager) == 1
        doc = json.loads(manager[0].payload.to_string())
        assert doc["cromat/r1/@manager/state"]["type"] == "bbcs.contracts.mri:RobotState"
        assert "bbcs.contracts.mri:SwapRoute" in doc["cromat/r1/@manager/route"]["request"]["type"]
        reply = next(r.ok for r in s.get("cromat/r1/@manager/modules", payload=mri.encode(mri.ListModules()),
                                          timeout=20) if r.ok is not None)
        assert str(reply.encoding) == "application/msgpack;bbcs.contracts.mri:MriReply"
    finally:
        la.cleanup()
