"""The flight-safety monitor as a test oracle: attach one to a launched robot, fly, then assert it saw no breach.

    truth = free_udp_port()
    la, record = launch_robot(tmp_path, edit=send_truth_to(truth))   # the DSP simulator sends its truth there
    with attach_monitor(la.port, tmp_path, truth_port=truth) as monitor:
        ... fly ...
        monitor.assert_no_breaches()          # every breach shown with its evidence

The monitor runs as its own process (``python -m modules.safety_monitor``) on the robot's router, as it would on a
robot; this helper only reads its ``breach`` and ``status`` slots.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import msgspec

from bbcs import keys
from bbcs.contracts.safety import BREACH_SLOT, MODULE, STATUS_SLOT, Breach, MonitorStatus
from bbcs.session import local_client, open_session
from bbcs.testing import child_env, stop_process, wait_until

ROOT = Path(__file__).resolve().parents[2]
CONF = ROOT / "bbcs_conf" / "uav1.conf"


def free_udp_port() -> int:
    """A UDP port free on 127.0.0.1 right now (for the simulator's truth datagrams)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def send_truth_to(port: int) -> Callable[[str], str]:
    """A manifest edit (``sim_manifest(edit=...)``): the DSP simulator sends its truth to 127.0.0.1:``port``."""
    def edit(text: str) -> str:
        old = '"--tcp", "127.0.0.1:{port:dsp}"'
        assert old in text, "the DSP simulator's command line changed"
        return text.replace(old, f'{old}, "--truth-udp", "127.0.0.1:{port}"', 1)
    return edit


class MonitorView:
    """What the attached monitor published: every breach, its latest status."""

    def __init__(self, proc: subprocess.Popen, log: Path) -> None:
        self.proc = proc
        self.log = log
        self.lock = threading.Lock()
        self.breaches: list[Breach] = []
        self.status: MonitorStatus | None = None

    def on_breach(self, breach: Breach) -> None:
        with self.lock:
            self.breaches.append(breach)

    def on_status(self, status: MonitorStatus) -> None:
        with self.lock:
            self.status = status

    def seen(self) -> list[Breach]:
        with self.lock:
            return list(self.breaches)

    def wait_watching(self, timeout_s: float = 30.0, truth: bool = True) -> MonitorStatus:
        """Until the monitor has the task book, DSP telemetry, the GRI and (``truth``) the simulator's truth."""
        def ready() -> bool:
            st = self.status
            if self.proc.poll() is not None:
                raise AssertionError(f"the monitor exited {self.proc.returncode}: {self.log.read_text()[-2000:]}")
            return st is not None and st.books > 0 and st.telemetry > 0 and st.gri_states > 0 \
                and (st.truth > 0 or not truth)
        wait_until(ready, timeout_s, "the safety monitor watching the robot")
        assert self.status is not None
        return self.status

    def wait_breach(self, pred: Callable[[Breach], bool], timeout_s: float, what: str) -> Breach:
        found: list[Breach] = []

        def seen() -> bool:
            found[:] = [b for b in self.seen() if pred(b)]
            return bool(found)

        try:
            wait_until(seen, timeout_s, what)
        except AssertionError as exc:
            raise AssertionError(f"{exc}\n{self.explain()}") from None
        return found[0]

    def explain(self) -> str:
        """What the monitor saw and said, for a failure message."""
        seen = "\n".join(b.describe() for b in self.seen()) or "no breach"
        tail = self.log.read_text()[-3000:] if self.log.exists() else ""
        return f"monitor status: {self.status}\nbreaches:\n{seen}\nmonitor log (tail):\n{tail}"

    def settle(self, timeout_s: float = 10.0) -> MonitorStatus:
        """Until every command seen so far is judged (a command waits for the task book to catch up)."""
        def judged() -> bool:
            st = self.status
            return st is not None and st.commands_judged == st.commands
        try:
            wait_until(judged, timeout_s, "the monitor judging every command it saw")
        except AssertionError as exc:
            raise AssertionError(f"{exc}\n{self.explain()}") from None
        assert self.status is not None
        return self.status

    def assert_no_breaches(self, breaches: list[Breach] | None = None) -> None:
        found = self.seen() if breaches is None else breaches
        if found:
            text = "\n".join(b.describe() for b in found)
            raise AssertionError(f"the safety monitor saw {len(found)} breach(es):\n{text}")


@contextmanager
def attach_monitor(router_port: int, tmp_path: Path, *, robot: str = "uav1", conf: Path = CONF,
                   truth_port: int | None = None, env: dict[str, str] | None = None,
                   params: dict[str, str] | None = None) -> Iterator[MonitorView]:
    """Run a safety monitor on the robot's router for the block; always stopped, its session closed. ``env``: more
    environment (a lockstep robot's ``CROMAT_SIM``: the monitor is then a member the simulation waits for);
    ``params``: more of its parameters (a uQuad's ``vehicle``, ``truth_tcp``)."""
    log = tmp_path / "safety_monitor.log"
    args = [sys.executable, "-m", "modules.safety_monitor", "--robot", robot, "--connect",
            f"tcp/127.0.0.1:{router_port}", "--conf", str(conf)]
    if truth_port is not None:
        args += ["--param", f"truth_udp={truth_port}"]
    for name, value in (params or {}).items():
        args += ["--param", f"{name}={value}"]
    with open(log, "w") as out:
        proc = subprocess.Popen(args, cwd=str(ROOT), env=child_env(**(env or {})), stdout=out, stderr=subprocess.STDOUT)
    view = MonitorView(proc, log)
    session = None
    subs = []
    try:
        session = open_session(local_client(router_port))
        for slot, typ, handler in ((BREACH_SLOT, Breach, view.on_breach), (STATUS_SLOT, MonitorStatus,
                                                                            view.on_status)):
            decode = msgspec.msgpack.Decoder(typ).decode
            subs.append(session.declare_subscriber(
                keys.slot_key(robot, MODULE, slot),
                lambda sample, d=decode, h=handler: h(d(sample.payload.to_bytes()))))
        yield view
    finally:
        for sub in subs:
            sub.undeclare()
        if session is not None:
            session.close()
        stop_process(proc)
