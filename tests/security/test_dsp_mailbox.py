"""Issue 32 item 5: the DSP's old shared command mailbox (``dsp/commands``) is gone, so a bus without TLS, where the
router checks nobody, cannot use it to send the aircraft a class no sender key carries ("pan_tilt" and "nobody"
sent ``SetMode`` that way). Judged at the DSP simulator's record: what was put there reached nothing; a PING on the
path follower's own key, put after it by the same session, did."""

from __future__ import annotations

import select
import subprocess
from pathlib import Path

import msgspec

from bbcs import keys
from bbcs.contracts import dsp as bus
from bbcs.contracts import dsp as p
from bbcs.testing import wait_until
from modules.dsp.sim.record import read_record

ROBOT = "uav1"
UAV1 = Path(__file__).resolve().parents[2] / "bbcs_conf" / "uav1.conf"


def test_the_old_mailbox_reaches_no_aircraft(processes, router, sessions, tmp_path: Path) -> None:
    record = tmp_path / "dsp.jsonl"
    sim = processes.start(["-m", "modules.dsp.sim", "--pty", "--record", str(record)], stdout=subprocess.PIPE,
                          text=True)
    assert select.select([sim.stdout], [], [], 15.0)[0], "the simulator printed nothing"
    pty = sim.stdout.readline().strip()
    processes.start(["-m", "modules.dsp", "--robot", ROBOT, "--connect", f"tcp/127.0.0.1:{router}", "--conf",
                     str(UAV1), "--param", f"port={pty}"], stderr=subprocess.DEVNULL)
    s = sessions()
    link: list[bytes] = []
    sub = s.declare_subscriber(keys.slot_key(ROBOT, bus.MODULE, bus.LINK_SLOT), lambda x: link.append(b""))
    try:
        wait_until(lambda: bool(link), 60, "the DSP process started up")
        startup = len(read_record(record))
        old = s.declare_publisher(keys.slot_key(ROBOT, bus.MODULE, "commands"))
        own = s.declare_publisher(keys.slot_key(ROBOT, bus.MODULE, bus.commands_slot("path_follower")))
        wait_until(lambda: own.matching_status.matching, 20, "the DSP's path follower input")
        for sender in ("pan_tilt", "nobody"):
            old.put(msgspec.msgpack.encode(bus.DspCommands(sender=sender, commands=[p.SetMode(mode=p.Mode(4))])))
        own.put(msgspec.msgpack.encode(bus.DspCommands(sender="path_follower", commands=[p.Ping()])))
        wait_until(lambda: len(read_record(record)) > startup, 30, "the PING at the simulator")
        assert [c["name"] for c in read_record(record)[startup:]] == ["PING"]
        assert not old.matching_status.matching, "something still reads the old mailbox"
        old.undeclare()
        own.undeclare()
    finally:
        sub.undeclare()
