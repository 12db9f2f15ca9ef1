"""DspLink over real transports (pty, socket://, loop://) against the simulator or a scripted far end."""

from __future__ import annotations

import os
import socket
import threading
import time
from collections.abc import Callable, Iterator

import pytest

from bbcs.contracts import dsp as p
from bbcs.geodesy import metres_per_degree
from bbcs.testing import wait_until
from modules.dsp import codec
from modules.dsp.config import load_dsp_config
from modules.dsp.errors import DspLinkError, DspPreempted, DspRejected, DspTimeout
from modules.dsp.framing import Frame, FrameParser
from modules.dsp.link import DspLink, startup, startup_commands
from modules.dsp.sim import DspSimulator, FaultInjector, PtyEndpoint, TcpEndpoint

from .conftest import UAV1

CLEAN_ACK_S = 2.0
"""Acknowledgement timeout where a test counts retries on a clean line: a late ack on a loaded machine must not
look like a lost frame (an ack that comes costs nothing)."""


@pytest.fixture
def sim() -> Iterator[DspSimulator]:
    s = DspSimulator(PtyEndpoint(), time_scale=10.0).start()
    try:
        yield s
    finally:
        s.stop()


class FarEnd:
    """A scripted DSP on the master side of a pty: ``reply(frame) -> bytes`` decides what goes back."""

    def __init__(self, reply: Callable[[Frame], bytes]) -> None:
        self.master, self.slave = os.openpty()
        import tty

        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.reply = reply
        self.frames: list[Frame] = []
        self.raw = bytearray()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        import select

        parser = FrameParser(codec.PC_TO_DSP_LENGTHS)
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.02)
            if not ready:
                continue
            try:
                data = os.read(self.master, 4096)
            except OSError:
                continue
            self.raw += data
            for frame in parser.feed(data):
                self.frames.append(frame)
                out = self.reply(frame)
                if out:
                    os.write(self.master, out)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        os.close(self.master)
        os.close(self.slave)


@pytest.fixture
def far_end() -> Iterator[Callable[[Callable[[Frame], bytes]], FarEnd]]:
    made: list[FarEnd] = []

    def make(reply: Callable[[Frame], bytes]) -> FarEnd:
        made.append(FarEnd(reply))
        return made[-1]

    try:
        yield make
    finally:
        for f in made:
            f.close()


def ack_for(frame: Frame, status: int = 0) -> bytes:
    return codec.encode(p.Ack(acked_id=frame.msg_id, acked_seq=frame.seq, status=status), 0)


def test_startup_over_a_pty_reaches_the_simulator_in_order(sim: DspSimulator) -> None:
    conf = load_dsp_config(UAV1, port=sim.endpoint.path)  # type: ignore[attr-defined]
    with DspLink(conf.port, conf.baudrate, ack_timeout=CLEAN_ACK_S) as link:
        acks = startup(link, conf)
        assert len(acks) == 16 and all(a.ok for a in acks)
        wait_until(lambda: link.latest_telemetry is not None, what="first telemetry frame")
        stats = link.stats()
    assert [c.name for c in sim.commands] == [codec.message_name(c.MSG_ID) for c in startup_commands(conf)]
    snap = sim.snapshot()
    assert snap.heli_type == p.HeliType.H3_CCPM_120 and snap.pid_axes == tuple(range(9))
    assert snap.state_tx and snap.telemetry_mask == p.TELEMETRY_ALL and snap.speed_cmd == 0.0
    assert stats.commands_acked == 16 and stats.retries == 0 and stats.frames_dropped == 0


def test_socket_url_and_callbacks() -> None:
    errors: list[p.DspError] = []
    telemetry: list[p.Telemetry] = []
    s = DspSimulator(TcpEndpoint(), time_scale=5.0, fail_at=[(0.5, int(p.ErrorCode.GPS_LOST))]).start()
    try:
        url = f"socket://127.0.0.1:{s.endpoint.port}"  # type: ignore[attr-defined]
        with DspLink(url, on_telemetry=telemetry.append, on_error=errors.append) as link:
            link.send(p.SetTelemetryMask(mask=int(p.TelemetryField.STATUS | p.TelemetryField.ERROR)))
            link.send(p.SetStateTransmission(enable=True, period_ms=20))
            wait_until(lambda: len(errors) == 1 and len(telemetry) > 20, what="an error and telemetry")
            assert errors[0].code == p.ErrorCode.GPS_LOST
            wait_until(lambda: telemetry[-1].error_code == p.ErrorCode.GPS_LOST, what="latched code in telemetry")
            assert link.ping().ok
            assert link.stats().dsp_errors == 1 and link.stats().dsp_frames_lost == 0
    finally:
        s.stop()


def test_missing_port_is_a_clear_error() -> None:
    with pytest.raises(DspLinkError, match="DSP port /dev/ttyDSP-missing: the port does not exist"):
        DspLink("/dev/ttyDSP-missing")


def test_busy_port_is_a_clear_error(sim: DspSimulator) -> None:
    path = sim.endpoint.path  # type: ignore[attr-defined]
    with DspLink(path):
        with pytest.raises(DspLinkError, match="busy"):
            DspLink(path)


def test_nothing_listening_on_a_socket() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(DspLinkError, match="cannot open DSP port socket://127.0.0.1"):
        DspLink(f"socket://127.0.0.1:{port}")


def test_silent_dsp_times_out_naming_the_command(far_end) -> None:
    end = far_end(lambda frame: b"")  # hears everything, answers nothing
    with DspLink(end.path, ack_timeout=0.05, retries=2) as link:
        with pytest.raises(DspTimeout, match=r"for Ping \(seq \d+\) after 3 attempts of 0.05 s") as info:
            link.ping()
        stats = link.stats()
    assert info.value.command == "Ping" and info.value.attempts == 3
    assert stats.retries == 2 and stats.timeouts == 1 and stats.frames_sent == 3
    wait_until(lambda: len(end.frames) == 3, what="three copies at the far end")
    assert len({f.seq for f in end.frames}) == 1  # a retry is the same frame


def test_an_abort_takes_the_line_from_a_command_waiting_for_its_ack(far_end) -> None:
    """A silent DSP holds a command for its whole retry budget (here 4 x 1 s); an ABORT must not wait behind it."""
    end = far_end(lambda frame: ack_for(frame) if frame.msg_id == p.MsgId.ABORT else b"")  # only ABORT answered
    with DspLink(end.path, ack_timeout=1.0, retries=3) as link:
        waiting: list[BaseException] = []

        def send_speed() -> None:
            try:
                link.send(p.SetSpeed(speed=1.0))
            except DspLinkError as exc:
                waiting.append(exc)

        sender = threading.Thread(target=send_speed)
        sender.start()
        wait_until(lambda: len(end.frames) == 1, what="the SetSpeed on the line")
        asked = time.monotonic()
        assert link.abort().ok
        took = time.monotonic() - asked
        sender.join(5)
        assert isinstance(waiting[0], DspPreempted) and waiting[0].command == "SetSpeed"
        assert [codec.message_name(f.msg_id) for f in end.frames] == ["SET_SPEED", "ABORT"]  # no retry of it
        assert took < 0.9, f"the ABORT waited {took:.2f} s behind the SetSpeed"  # its first retry was due at 1 s
        assert link.stats().preempted == 1


def test_an_abort_is_not_preempted_by_the_next(far_end) -> None:
    answered: list[Frame] = []

    def second_abort_answered(frame: Frame) -> bytes:
        answered.append(frame)
        return ack_for(frame) if len(answered) > 1 else b""  # the first copy of the ABORT lost

    end = far_end(second_abort_answered)
    with DspLink(end.path, ack_timeout=0.3, retries=3) as link:
        result: list[p.Ack] = []
        first = threading.Thread(target=lambda: result.append(link.abort()))
        first.start()
        wait_until(lambda: len(end.frames) == 1, what="the first ABORT on the line")
        link.preempt()  # a second ABORT arriving: the first keeps waiting for its ACK and is resent
        first.join(5)
        assert result and result[0].ok and link.stats().preempted == 0


def test_loopback_hears_only_its_own_commands() -> None:
    with DspLink("loop://", ack_timeout=0.05, retries=1) as link:
        with pytest.raises(DspTimeout):
            link.send(p.SetSpeed(speed=0.0))
        # the reader thread may not have parsed the second copy yet when the sender gives up
        wait_until(lambda: link.stats().unknown_id >= 2, what="both copies read back")
        assert link.stats().unknown_id == 2  # its own command frames, not valid PC-side ids


def test_a_lost_frame_is_resent_and_then_acknowledged(far_end) -> None:
    seen: list[Frame] = []

    def drop_first(frame: Frame) -> bytes:
        seen.append(frame)
        return b"" if len(seen) == 1 else ack_for(frame)

    end = far_end(drop_first)
    with DspLink(end.path, ack_timeout=0.5, retries=3) as link:  # the first timeout is sure; the retry's ack must come
        ack = link.send(p.SetMode(mode=p.Mode.TAKE_OFF))
        assert ack.ok and link.stats().retries == 1
    assert seen[0] == seen[1]


def test_refused_command_raises_and_is_not_retried(far_end) -> None:
    end = far_end(lambda frame: ack_for(frame, p.ErrorCode.NOT_CONFIGURED))
    with DspLink(end.path, ack_timeout=CLEAN_ACK_S) as link:
        with pytest.raises(DspRejected, match="refused SetMode: NOT_CONFIGURED") as info:
            link.send(p.SetMode(mode=p.Mode.TAKE_OFF))
        assert info.value.status == p.ErrorCode.NOT_CONFIGURED
        assert link.stats().nacks == 1 and link.stats().retries == 0


def test_out_of_range_sends_nothing(far_end) -> None:
    end = far_end(ack_for)
    with DspLink(end.path) as link:
        with pytest.raises(p.DspValueError):
            link.send(p.SetSpeed(speed=100.0))
        with pytest.raises(p.DspValueError):  # one bad point: none of the list is sent
            link.send_waypoints([p.AddWaypoint(lat=10, lon=10, alt=5), p.AddWaypoint(lat=100, lon=10, alt=5)])
        assert link.ping().ok
        assert link.stats().frames_sent == 1
    assert [f.msg_id for f in end.frames] == [p.MsgId.PING]


def test_false_start_then_silence_does_not_hide_the_ack(far_end) -> None:
    false_header = bytes([0xA5, 0x5A, 107, p.MsgId.TELEMETRY, 0])  # claims 114 bytes that never come
    end = far_end(lambda frame: false_header + ack_for(frame))
    with DspLink(end.path, ack_timeout=CLEAN_ACK_S, retries=0) as link:
        assert link.ping().ok
        assert link.stats().truncated == 1


def test_lossy_line_retries_without_duplicating_waypoints() -> None:
    tx = FaultInjector(corrupt=0.004, garbage=0.02, seed=11,
                       false_ids={i: max(v) for i, v in codec.DSP_TO_PC_LENGTHS.items()})
    rx = FaultInjector(corrupt=0.004, garbage=0.02, seed=12)
    s = DspSimulator(PtyEndpoint(), time_scale=5.0, tx_faults=tx, rx_faults=rx).start()
    try:
        with DspLink(s.endpoint.path, ack_timeout=0.25, retries=10) as link:  # type: ignore[attr-defined]
            link.send(p.SetTelemetryMask(mask=p.TELEMETRY_ALL))
            link.send(p.SetStateTransmission(enable=True, period_ms=20))
            home = s.machine.params
            points = [p.AddWaypoint(lat=home.home_lat + i * 1e-4, lon=home.home_lon, alt=30.0)
                      for i in range(60)]
            assert link.send_waypoints(points) == 60
            stats = link.stats()
        assert s.snapshot().queue_length == 60  # every retransmission recognised as such
        assert stats.retries > 0 and stats.bad_crc > 0 and stats.telemetry_frames > 0
        applied = [c for c in s.commands if c.name == "ADD_WAYPOINT" and not c.duplicate]
        assert [c.fields["lat"] for c in applied] == [codec.unscale_latlon(codec.scale_latlon(pt.lat))
                                                      for pt in points]
    finally:
        s.stop()


def test_abort_stops_a_waypoint_list_and_empties_the_queue(sim: DspSimulator) -> None:
    home = sim.machine.params
    points = [p.AddWaypoint(lat=home.home_lat + (i % 100) * 1e-4, lon=home.home_lon, alt=30.0)
              for i in range(400)]
    with DspLink(sim.endpoint.path) as link:  # type: ignore[attr-defined]
        result: list[int] = []
        sender = threading.Thread(target=lambda: result.append(link.send_waypoints(points)))
        sender.start()
        wait_until(lambda: sim.snapshot().queue_length >= 20, what="some waypoints queued")
        assert link.abort().ok
        sender.join(30)
    assert result and 20 <= result[0] < 400
    assert sim.snapshot().queue_length == 0 and not sim.snapshot().path_valid
    names = [c.name for c in sim.commands]
    # the waypoint on the line when the abort came was not waited for: recorded, unacknowledged, emptied by it
    assert names[-1] == "ABORT" and names.count("ADD_WAYPOINT") in (result[0], result[0] + 1)


def test_port_vanishing_is_reported_not_hung() -> None:
    s = DspSimulator(PtyEndpoint(), time_scale=1.0).start()
    link = DspLink(s.endpoint.path, ack_timeout=1.0, retries=1)  # type: ignore[attr-defined]
    try:
        assert link.ping().ok
        s.stop()  # the DSP end disappears
        wait_until(lambda: link.failure is not None, what="the reader noticing")
        with pytest.raises(DspLinkError, match="failed"):
            link.ping()
    finally:
        link.close()
        s.stop()


def test_close_is_idempotent_and_final(sim: DspSimulator) -> None:
    link = DspLink(sim.endpoint.path)  # type: ignore[attr-defined]
    link.close()
    link.close()
    assert link.closed
    with pytest.raises(DspLinkError, match="closed"):
        link.ping()


def test_wrong_baud_gives_garbage_and_a_timeout() -> None:
    s = DspSimulator(PtyEndpoint(baud=921_600), baud=921_600, time_scale=1.0).start()
    try:
        conf = load_dsp_config(UAV1, port=s.endpoint.path)  # type: ignore[attr-defined]
        with DspLink(conf.port, 115_200, ack_timeout=0.05, retries=2) as link:
            with pytest.raises(DspTimeout, match="SetSpeed"):
                startup(link, conf)
            sent = link.stats().bytes_tx
        # at 1/8 of its speed every byte the PC sent reaches the DSP as one byte of noise: once all are in, the
        # simulator has decoded (or not) everything
        wait_until(lambda: s.rx_stats["bytes_in"] >= sent, what="every byte sent read by the simulator")
        assert s.baud_mismatch and s.commands == []
    finally:
        s.stop()


def test_waypoint_goes_out_quantised_to_1e_4_degree(sim: DspSimulator) -> None:
    with DspLink(sim.endpoint.path) as link:  # type: ignore[attr-defined]
        link.send(p.AddWaypoint(lat=37.41234567, lon=-6.00256789, alt=40.25))
    rec = sim.commands[-1]
    assert rec.fields == {"type": "AddWaypoint", "lat": 37.4123, "lon": -6.0026, "alt": 40.25}
    error_m = abs(37.41234567 - 37.4123) * metres_per_degree(37.4123)[0]
    assert error_m < 5.6  # half a step of 1e-4 degree


def test_many_threads_share_one_link(sim: DspSimulator) -> None:
    with DspLink(sim.endpoint.path, ack_timeout=CLEAN_ACK_S) as link:  # type: ignore[attr-defined]
        errors: list[BaseException] = []

        def worker() -> None:
            try:
                for _ in range(25):
                    link.ping()
            except BaseException as exc:  # collected and asserted below
                errors.append(exc)

        threads = [threading.Thread(target=worker) for _ in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        stats = link.stats()
    assert not errors
    assert stats.commands_acked == 100 and stats.stray_acks == 0 and stats.retries == 0
    assert [c.name for c in sim.commands].count("PING") == 100


def test_a_simulators_socket_port_is_read_in_whole_chunks_not_byte_by_byte() -> None:
    """pyserial's ``socket://`` port says 0 or 1 byte waiting whatever is there; the link's reader asks the socket,
    so 3 KB of telemetry that arrived together come back in one read (byte by byte, a loaded machine's reader
    fell behind the simulator and ACKs came after their window)."""
    import serial

    from modules.dsp.link import bytes_waiting

    with socket.create_server(("127.0.0.1", 0)) as server:
        port = serial.serial_for_url(f"socket://127.0.0.1:{server.getsockname()[1]}", timeout=0.02)
        far, _ = server.accept()
        try:
            far.sendall(bytes(range(256)) * 12)
            assert port.in_waiting <= 1  # pyserial's answer, the reason for bytes_waiting
            wait_until(lambda: bytes_waiting(port) == 3072, 5, "3 KB at the port")
            assert port.read(bytes_waiting(port)) == bytes(range(256)) * 12
            assert bytes_waiting(port) == 0
        finally:
            far.close()
            port.close()
