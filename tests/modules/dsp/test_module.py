"""The DSP process on a real router with the DSP simulator on a real pty: start-up first, command batches,
limits, refusals, ABORT flushing, DSP errors forwarded, and clean failures (missing port, silent DSP)."""

from __future__ import annotations

import os
import select
import subprocess
import threading
import tty
from pathlib import Path

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts import dsp as bus
from bbcs.contracts import dsp as p
from bbcs.contracts.dsp import LinkErrorCode, LinkStats
from bbcs.errors import EXIT_CONFIG
from bbcs.slots import Kind, OutputSlot, Publisher
from bbcs.testing import stop_process, wait_until
from modules.dsp.config import load_dsp_config
from modules.dsp.link import startup_commands
from modules.dsp.sim.record import read_record

from .conftest import UAV1

ROBOT = "r1"
STOP_S = 20.0  # a loaded machine may take seconds to stop a Zenoh process: the exit code is what is checked


def start_sim(processes, *args: str) -> str:
    proc = processes.start(["-m", "modules.dsp.sim", "--pty", *args], stdout=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 15.0)
    assert ready, "the simulator printed nothing"
    return proc.stdout.readline().strip()


def start_dsp(processes, router: int, port: str) -> subprocess.Popen:
    args = ["-m", "modules.dsp", "--robot", ROBOT, "--connect", f"tcp/127.0.0.1:{router}",
            "--conf", str(UAV1), "--param", f"port={port}"]
    return processes.start(args, stderr=subprocess.PIPE, text=True)


class Bus:
    """The test's view of the DSP process's output slots, and a sender of command batches."""

    def __init__(self, session) -> None:
        self.telemetry: list[p.Telemetry] = []
        self.reports: list[bus.DspErrorReport] = []
        self.link: list[LinkStats] = []
        self.lock = threading.Lock()
        subs = []
        for slot, typ, sink in ((bus.TELEMETRY_SLOT, p.Telemetry, self.telemetry),
                                (bus.ERRORS_SLOT, bus.DspErrorReport, self.reports),
                                (bus.LINK_SLOT, LinkStats, self.link)):
            decode = msgspec.msgpack.Decoder(typ).decode
            key = keys.slot_key(ROBOT, bus.MODULE, slot)
            subs.append(session.declare_subscriber(
                key, lambda s, d=decode, k=sink: self._add(k, d(s.payload.to_bytes()))))
        self.subs = subs
        self.pubs = {s: Publisher(session, keys.slot_key(ROBOT, bus.MODULE, bus.commands_slot(s)),
                                  OutputSlot(bus.commands_slot(s), bus.DspCommands, kind=Kind.STREAM))
                     for s in bus.COMMAND_RIGHTS}
        self.batches = 0

    def _add(self, sink: list, value: object) -> None:
        with self.lock:
            sink.append(value)

    def send(self, *commands: bus.DspCommand, sender: str = "path_follower") -> int:
        """A batch on ``sender``'s own key (there is no shared mailbox)."""
        self.batches += 1
        self.pubs[sender].publish(bus.DspCommands(sender="field", commands=list(commands), batch_id=self.batches))
        return self.batches

    def close(self) -> None:
        for pub in self.pubs.values():
            pub.close()
        for sub in self.subs:
            sub.undeclare()


@pytest.fixture
def rig(processes, router, sessions, tmp_path: Path):
    record = tmp_path / "dsp.jsonl"
    pty = start_sim(processes, "--time-scale", "10", "--record", str(record), "--fail", "GPS_LOST@40")
    view = Bus(sessions())
    try:
        proc = start_dsp(processes, router, pty)
        # telemetry flows from the start-up's third command on; the first link statistics come once it is done
        wait_until(lambda: len(view.telemetry) > 5 and bool(view.link), what="DSP start-up done", deadline_s=30)
        yield proc, view, record
    finally:
        view.close()


def names(record: Path) -> list[str]:
    """Names of the commands the simulator applied (``read_record``: whole lines, retransmissions left out)."""
    return [c["name"] for c in read_record(record)]


def batch_reports(view: Bus) -> list[bus.DspErrorReport]:
    """The reports about command batches: without the GPS_LOST the rig's simulator raises at 40 simulated
    seconds (about 4 s of wall time in, so a slow run sees it in any test)."""
    with view.lock:
        return [r for r in view.reports if r.code != p.ErrorCode.GPS_LOST]


def test_startup_first_then_batches_in_order(rig) -> None:
    proc, view, record = rig
    startup = [c.MSG_ID.name for c in startup_commands(load_dsp_config(UAV1))]
    assert names(record) == startup  # nothing else before the start-up sequence, and all of it
    view.send(p.SetSpeed(speed=3.0), p.SetMode(mode=p.Mode.TAKE_OFF))
    # two senders' keys have no order between them: the second batch once the first is at the DSP
    wait_until(lambda: len(names(record)) == len(startup) + 2, what="the first batch at the DSP")
    view.send(p.SetPanTiltMode(mode=p.PanTiltMode.ANGLES), p.SetPanTiltAngles(pan_deg=20, tilt_deg=-10),
              sender="pan_tilt")
    wait_until(lambda: len(names(record)) == len(startup) + 4, what="both batches at the DSP")
    assert names(record)[len(startup):] == ["SET_SPEED", "SET_MODE", "SET_PT_MODE", "SET_PT_ANGLES"]
    wait_until(lambda: view.telemetry[-1].status.mode == p.Mode.TAKE_OFF and view.telemetry[-1].status.airborne,
               what="taking off, seen in bus telemetry")
    wait_until(lambda: bool(view.link) and view.link[-1].commands_acked >= len(startup) + 4, what="link statistics")
    assert not batch_reports(view)
    assert proc.poll() is None


def test_limits_and_refusals_are_reported_with_the_sender(rig) -> None:
    _, view, record = rig
    before = len(names(record))
    batch = view.send(p.SetSpeed(speed=9.0), p.SetMode(mode=p.Mode.TAKE_OFF), sender="path_follower")
    wait_until(lambda: len(batch_reports(view)) == 1, what="the MAX_SPEED report")
    r = batch_reports(view)[0]
    assert (r.code, r.sender, r.batch_id, r.command) == (LinkErrorCode.OVER_MAX_SPEED, "path_follower", batch,
                                                         "SetSpeed")
    refs = p.SetRefs(ref_altura=30, error_longitudinal=1, error_lateral=0, ref_heading=0, ref_rpm_motor=1500)
    batch = view.send(refs, p.SetMode(mode=p.Mode.TAKE_OFF))  # REFS outside bridge mode
    wait_until(lambda: len(batch_reports(view)) == 2, what="the refusal report")
    r = batch_reports(view)[1]
    expected = (p.ErrorCode.WRONG_MODE, "WRONG_MODE", "path_follower", batch, "SetRefs")
    assert (r.code, r.name, r.sender, r.batch_id, r.command) == expected
    # one sender thread, one line: a later batch's command at the DSP shows nothing else of these is coming
    view.send(p.SetSpeed(speed=3.0))
    wait_until(lambda: len(names(record)) >= before + 2, what="the marker batch at the DSP")
    assert names(record)[before:] == ["SET_REFS", "SET_SPEED"]  # nothing after the refused command, nothing of batch 1


def test_abort_flushes_queued_batches_and_the_dsp_queue(rig) -> None:
    _, view, record = rig
    home = (37.4117, -6.0025)
    wps = [p.AddWaypoint(lat=home[0] + (i % 50) * 1e-4, lon=home[1], alt=40.0) for i in range(300)]
    first, _, third = (view.send(*wps) for _ in range(3))
    view.send(p.Abort())
    wait_until(lambda: "ABORT" in names(record), what="the ABORT at the DSP")
    wait_until(lambda: any(r.batch_id == third and r.code == LinkErrorCode.FLUSHED for r in view.reports),
               what="the third batch reported flushed")
    sent = names(record)
    print(f"\n{sent.count('ADD_WAYPOINT')} of 900 waypoints sent before the ABORT")
    assert sent.count("ADD_WAYPOINT") < 900 and sent[-1] == "ABORT"
    wait_until(lambda: view.telemetry[-1].status.queue_length == 0 and not view.telemetry[-1].status.path_valid,
               what="the DSP's queue empty")
    # one sender thread, one line: a later batch's command at the DSP shows nothing more of the path is coming
    view.send(p.SetSpeed(speed=3.0))
    wait_until(lambda: len(names(record)) > len(sent), what="the marker batch at the DSP")
    assert names(record)[len(sent) - 1:] == ["ABORT", "SET_SPEED"]
    assert {r.sender for r in batch_reports(view)} == {"path_follower"} and first < third


def test_dsp_errors_are_forwarded(rig) -> None:
    _, view, _ = rig
    wait_until(lambda: any(r.code == p.ErrorCode.GPS_LOST for r in view.reports),
               what="GPS_LOST from the DSP", deadline_s=30)
    r = next(r for r in view.reports if r.code == p.ErrorCode.GPS_LOST)
    assert r.name == "GPS_LOST" and r.sender == "" and "DSP reported" in r.detail


def test_missing_port_exits_with_a_clear_error(processes, router) -> None:
    proc = start_dsp(processes, router, "/dev/ttyDSP-missing")
    assert proc.wait(20) == 3
    assert "cannot open DSP port /dev/ttyDSP-missing: the port does not exist" in proc.stderr.read()


def test_invalid_conf_exits_with_the_configuration_status(processes, router, tmp_path) -> None:
    """A bad .conf value is a configuration error (exit 78, which the manager never restarts), named with
    file:line, and the DSP port is never opened."""
    conf = tmp_path / "bad.conf"
    conf.write_text(UAV1.read_text().replace("MAX_SPEED: 8.0", "MAX_SPEED: fast"))
    line = next(i for i, t in enumerate(conf.read_text().splitlines(), 1) if t.startswith("MAX_SPEED"))
    args = ["-m", "modules.dsp", "--robot", ROBOT, "--connect", f"tcp/127.0.0.1:{router}",
            "--conf", str(conf), "--param", "port=/dev/ttyDSP-never-opened"]
    proc = processes.start(args, stderr=subprocess.PIPE, text=True)
    assert proc.wait(20) == EXIT_CONFIG
    err = proc.stderr.read()
    assert f"{conf}:{line}:1: key 'MAX_SPEED': invalid value 'fast'" in err
    assert "cannot open DSP port" not in err


def test_silent_dsp_exits_with_a_clear_error(processes, router) -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        proc = start_dsp(processes, router, os.ttyname(slave))
        assert proc.wait(20) == 3
        err = proc.stderr.read()
        assert "start-up sequence failed" in err and "no acknowledgement" in err and "SetSpeed" in err
    finally:
        os.close(master)
        os.close(slave)


def test_stops_cleanly(rig) -> None:
    proc, _, _ = rig
    assert stop_process(proc, STOP_S) == 0


def test_misspelt_param_exits_with_the_configuration_status(processes, router) -> None:
    """A manifest param the DSP does not know is a configuration error (exit 78, never restarted), the nearest
    known name given, before the port is opened."""
    args = ["-m", "modules.dsp", "--robot", ROBOT, "--connect", f"tcp/127.0.0.1:{router}",
            "--conf", str(UAV1), "--param", "prot=/dev/ttyDSP-never-opened"]
    proc = processes.start(args, stderr=subprocess.PIPE, text=True)
    assert proc.wait(20) == EXIT_CONFIG
    err = proc.stderr.read()
    assert "prot: unknown dsp parameter (did you mean port?" in err and "cannot open DSP port" not in err
