"""Issue 12 item 6, by effect: the DSP simulator sends telemetry frames with a good CRC and latitude 200°, roll
+inf or heading NaN; the real DSP process drops each one (never on ``dsp/telemetry``), counts it (``dsp/link``) and
reports it on its ERROR slot as TELEMETRY_REFUSED, a run of them at most once a second (issue 30 case 3), and
keeps publishing the good frames."""

from __future__ import annotations

import math
import select
import subprocess
import threading
import time
from pathlib import Path

import msgspec

from bbcs import keys
from bbcs.contracts import dsp as bus
from bbcs.contracts import dsp as p
from bbcs.contracts.errors import ErrorReport
from bbcs.testing import wait_until

ROOT = Path(__file__).resolve().parents[2]
UAV1 = ROOT / "bbcs_conf" / "uav1.conf"
ROBOT = "r1"


def start_sim(processes, *args: str) -> str:
    proc = processes.start(["-m", "modules.dsp.sim", *args], stdout=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 15.0)
    assert ready, "the simulator printed nothing"
    return proc.stdout.readline().strip()


def start_dsp(processes, router: int, port: str) -> subprocess.Popen:
    return processes.start(["-m", "modules.dsp", "--robot", ROBOT, "--connect", f"tcp/127.0.0.1:{router}",
                            "--conf", str(UAV1), "--param", f"port={port}"], stderr=subprocess.DEVNULL)


class Seen:
    """Everything the DSP process publishes on telemetry, errors, link and its ERROR slot, as raw decoded values."""

    def __init__(self, session) -> None:
        self.lock = threading.Lock()
        self.telemetry: list[p.Telemetry] = []
        self.reports: list[bus.DspErrorReport] = []
        self.links: list[bus.LinkStats] = []
        self.codes: list[tuple[float, int]] = []
        self.subs = [
            self._sub(session, bus.TELEMETRY_SLOT, p.Telemetry, self.telemetry),
            self._sub(session, bus.ERRORS_SLOT, bus.DspErrorReport, self.reports),
            self._sub(session, bus.LINK_SLOT, bus.LinkStats, self.links),
            self._sub(session, "error", ErrorReport, self.codes, lambda e: (time.monotonic(), e.code)),
        ]

    def _sub(self, session, slot, typ, sink, pick=lambda v: v):
        decode = msgspec.msgpack.Decoder(typ).decode  # no range check here: we want to see whatever arrives

        def on(sample) -> None:
            with self.lock:
                sink.append(pick(decode(sample.payload.to_bytes())))
        return session.declare_subscriber(keys.slot_key(ROBOT, bus.MODULE, slot), on)

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()


def _bad(t: p.Telemetry) -> bool:
    try:
        p.check(t)
    except p.DspValueError:
        return True
    return False


def test_out_of_range_telemetry_is_dropped_counted_and_reported(processes, router, sessions) -> None:
    pty = start_sim(processes, "--pty", "--time-scale", "5", "--bad-telemetry", "4")
    seen = Seen(sessions())
    try:
        start_dsp(processes, router, pty)
        kinds = ("=200.0 is out of range [-90.0, 90.0]", "roll=inf must be finite", "heading=nan must be finite")

        def reasons() -> set[str]:
            with seen.lock:
                return {k for s in seen.links for k in kinds if k in s.last_refused}

        # all three spoilt kinds refused (they come in turn), each naming field, value and range
        wait_until(lambda: reasons() == set(kinds), what="the three kinds of out-of-range frames refused",
                   deadline_s=60)
        wait_until(lambda: len(seen.codes) >= 3, what="three reports on the ERROR slot", deadline_s=30)
        with seen.lock:
            published = list(seen.telemetry)
            codes = list(seen.codes)
            refused = max(s.telemetry_refused for s in seen.links)
            telemetry_reports = [r for r in seen.reports if "telemetry" in r.detail]
        # one code, on one slot: nothing on the errors stream (no module forwards it, no task fails on it)
        assert {code for _, code in codes} == {bus.LinkErrorCode.TELEMETRY_REFUSED}
        assert not telemetry_reports
        # coalesced: about 25 bad frames a second, at most one report a second
        assert refused > 3 * len(codes)
        span = codes[-1][0] - codes[0][0]
        assert len(codes) <= span / 1.0 + 2, (len(codes), span)
        # good frames still flow, and not one spoilt frame reached the bus
        assert len(published) > 2 * refused
        assert not [t for t in published if _bad(t)]
        assert all(t.position is None or abs(t.position.lat) <= 90 for t in published)
        assert all(t.attitude is None or math.isfinite(t.attitude.roll) for t in published)
        assert all(t.heading is None or math.isfinite(t.heading) for t in published)
    finally:
        seen.close()


def test_the_simulator_serves_one_client_and_refuses_a_second() -> None:
    import socket

    from modules.dsp import codec
    from modules.dsp.framing import FrameParser
    from modules.dsp.sim.server import DspSimulator
    from modules.dsp.sim.transport import TcpEndpoint

    endpoint = TcpEndpoint()
    sim = DspSimulator(endpoint).start()
    first = socket.create_connection((endpoint.host, endpoint.port), timeout=10)
    second = None
    try:
        parser = FrameParser(codec.DSP_TO_PC_LENGTHS)

        def ping(seq: int) -> None:
            first.sendall(codec.encode(p.Ping(), seq))
            while True:
                msgs = [codec.decode(f) for f in parser.feed(first.recv(4096))]
                if any(isinstance(m, p.Ack) and m.acked_seq == seq for m in msgs):
                    return

        ping(1)
        second = socket.create_connection((endpoint.host, endpoint.port), timeout=10)
        second.sendall(codec.encode(p.Ping(), 99))
        try:  # closed by the simulator without a byte (a reset when our unread frame was still queued)
            assert second.recv(4096) == b""
        except ConnectionResetError:
            pass
        ping(2)  # the first PC keeps its line
        assert endpoint.refused == 1
        assert [c.seq for c in sim.commands] == [1, 2]  # the second client's frame never reached the DSP
    finally:
        for s in (first, second):
            if s is not None:
                s.close()
        sim.stop()


def test_ldmrs_scans_outside_the_scanner_ranges_are_refused_whole() -> None:
    import numpy as np
    import pytest

    from modules.lidar_logger.ldmrs_proto import LdmrsProtocolError
    from modules.lidar_logger.ldmrs_scan import SCAN_HEADER, decode_scan, make_points

    def scan(angle: int, layer: int = 1, ticks: int = 11520, start: int = 1600) -> bytes:
        pts = make_points(np.array([layer]), np.array([0]), np.array([0]), np.array([angle]), np.array([1000]),
                          np.array([100]))
        return SCAN_HEADER.pack(7, 0, 0, 0, 0, ticks, start, -1920, 1, 0, 0, 0, 0, 0, 0, 0) + pts.tobytes()

    assert decode_scan(scan(0)).n_points == 1
    for bad, match in ((scan(2000), "point angle 2000"), (scan(-1921), "point angle -1921"),
                       (scan(0, ticks=11000), "ticks per rotation"), (scan(0, start=1700), "start angle"),
                       (scan(0, layer=5), "layer")):
        with pytest.raises(LdmrsProtocolError, match=match):
            decode_scan(bad)
