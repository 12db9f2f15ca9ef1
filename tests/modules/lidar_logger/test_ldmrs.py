"""LD-MRS driver against the simulator over TCP on 127.0.0.1: configuration, measuring, faults."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from modules.lidar_logger.ldmrs import LdmrsClient, LdmrsError, ScannerConfig
from modules.lidar_logger.ldmrs_proto import Cmd, Param
from modules.lidar_logger.ldmrs_scan import Scan
from modules.lidar_logger.sim import LdmrsOptions


@pytest.fixture
def client_factory():
    made: list[LdmrsClient] = []

    def make(port: int, **kw) -> LdmrsClient:
        c = LdmrsClient("127.0.0.1", port, **kw)
        made.append(c)
        c.connect()
        return c

    try:
        yield make
    finally:
        for c in made:
            c.close()


def wait_for(cond, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.01)


def test_configure_sets_and_reads_back_the_seed_parameters(make_world, start_ldmrs, client_factory) -> None:
    sim = start_ldmrs(make_world(10.0))
    client = client_factory(sim.port)
    readback = client.configure(ScannerConfig())
    assert readback == {
        "DATA_OUTPUT_FLAGS": 0xFFEE,
        "START_ANGLE": 1600,
        "END_ANGLE": (-1600) & 0xFFFF,
        "SCAN_FREQUENCY": 3200,
        "ANGULAR_RESOLUTION_TYPE": 1,
    }
    assert sim.device.params[Param.SCAN_FREQUENCY] == 3200 and sim.device.period == pytest.approx(0.08)
    sets = [(c, p, v) for _, c, p, v in sim.device.commands if c == Cmd.SET_PARAMETER]
    assert [p for _, p, _ in sets] == [
        Param.DATA_OUTPUT_FLAGS,
        Param.START_ANGLE,
        Param.END_ANGLE,
        Param.SCAN_FREQUENCY,
        Param.ANGULAR_RESOLUTION_TYPE,
    ]
    status = client.get_status()
    assert status.firmware == 0x2A31


def test_angles_are_written_in_the_order_that_keeps_start_above_end(
    make_world, start_ldmrs, client_factory
) -> None:
    sim = start_ldmrs(make_world(10.0))
    sim.device.params[Param.END_ANGLE] = 1000
    client = client_factory(sim.port)
    client.configure(ScannerConfig(start_angle_deg=25.0, end_angle_deg=-50.0))
    order = [p for _, c, p, _ in sim.device.commands if c == Cmd.SET_PARAMETER and p in (0x1100, 0x1101)]
    assert order == [Param.END_ANGLE, Param.START_ANGLE]
    assert (sim.device.start_ticks, sim.device.end_ticks) == (800, -1600)


def test_a_refused_command_raises(make_world, start_ldmrs, client_factory) -> None:
    sim = start_ldmrs(make_world(10.0))
    client = client_factory(sim.port)
    client.start_measure()
    with pytest.raises(LdmrsError, match="refused SET_PARAMETER 0x1102 = 3200"):
        client.set_parameter(Param.SCAN_FREQUENCY, 3200)  # the scanner refuses parameters while measuring
    client.stop_measure()


def test_config_values_are_checked_before_anything_is_sent() -> None:
    with pytest.raises(ValueError, match="greater than end"):
        ScannerConfig(start_angle_deg=-10, end_angle_deg=10)
    with pytest.raises(ValueError, match="12.5, 25 or 50"):
        ScannerConfig(frequency_hz=13.0)
    with pytest.raises(ValueError, match=r"\+50"):
        ScannerConfig(start_angle_deg=60.0)


def test_scans_arrive_intact_through_garbage_and_split_messages(
    make_world, start_ldmrs, client_factory
) -> None:
    sim = start_ldmrs(make_world(5.0), LdmrsOptions(garbage_every=3, split_sends=True, return_fraction=0.3))
    client = client_factory(sim.port)
    client.configure(ScannerConfig())
    got: list[Scan] = []
    client.on_scan = got.append
    client.start_measure()
    wait_for(lambda: len(got) >= 12)
    client.stop_measure()
    sent = sim.device.sent_scans
    assert len(got) == len(sent) >= 12
    for a, b in zip(got, sent, strict=True):
        assert a.scan_number == b.scan_number and a.start_ntp == b.start_ntp and a.scan_flags == b.scan_flags
        assert np.array_equal(a.points, b.points)
    assert client.parser.discarded_bytes > 0 and client.bad_scans == 0


def test_a_scanner_that_stops_answering_times_out(make_world, start_ldmrs, client_factory) -> None:
    sim = start_ldmrs(make_world(10.0), LdmrsOptions(silent_after=0.0, answer_when_silent=False))
    client = client_factory(sim.port, reply_timeout=0.3)
    client.start_measure()
    with pytest.raises(LdmrsError, match=r"STOP_MEASURE: no reply within 0.3 s"):
        client.stop_measure()


def test_unreachable_scanner() -> None:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    with pytest.raises(LdmrsError, match="cannot connect"):
        LdmrsClient("127.0.0.1", port, connect_timeout=1.0).connect()


def test_a_lost_connection_is_reported_and_fails_waiting_commands(
    make_world, start_ldmrs, client_factory
) -> None:
    sim = start_ldmrs(make_world(10.0), LdmrsOptions(silent_after=0.0, answer_when_silent=False))
    client = client_factory(sim.port, reply_timeout=5.0)
    client.start_measure()
    result: list[BaseException] = []

    def ask() -> None:
        try:
            client.get_status()
        except LdmrsError as exc:
            result.append(exc)

    t = threading.Thread(target=ask)
    t.start()
    # the request must be waiting for its reply when the connection goes: the scanner has it (and stays quiet)
    wait_for(lambda: any(c == Cmd.GET_STATUS for _, c, _, _ in sim.device.commands))
    sim.stop()
    t.join(timeout=30)
    wait_for(lambda: client.disconnected is not None)
    assert result and "closed the connection" in str(result[0])


def test_set_time_puts_the_scanner_clock_on_the_given_utc(make_world, start_ldmrs, client_factory) -> None:
    world = make_world(1.0)
    sim = start_ldmrs(world)
    client = client_factory(sim.port)
    before = world.now()
    client.set_time(world.utc(before) + 1234.5)
    after = world.now()
    # the scanner takes the time when SET_NTP_FRAC arrives, between the two readings: the offset is 1234.5 s
    # minus that latency, whatever it was (1e-5 s: float and NTP-fraction rounding)
    assert 1234.5 - (after - before) - 1e-5 <= sim.device.clock_offset <= 1234.5 + 1e-5


def test_cut_scans_are_reported_coalesced_and_the_next_scan_arrives() -> None:
    """A far end on 127.0.0.1 sends ten scans cut short, then a good one (all written by hand from the protocol,
    tests/modules/lidar_logger/test_ldmrs_proto.py::hand_scan): the good scan reaches on_scan, the cut ones are
    counted and reported to on_refused, the first at once and the other nine together about a second later."""
    from tests.modules.lidar_logger.test_ldmrs_proto import hand_scan

    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    scans: list[Scan] = []
    reports: list[tuple[float, str]] = []
    client = LdmrsClient("127.0.0.1", port)
    client.on_scan = scans.append
    client.on_refused = lambda text: reports.append((time.monotonic(), text))
    conn = None
    try:
        client.connect()
        conn, _ = server.accept()
        conn.sendall(hand_scan(1, 60)[:24 + 44 + 10 * 20])  # cut: known once the next header arrives
        conn.sendall(hand_scan(2, 60)[:24 + 44 + 10 * 20])
        wait_for(lambda: reports)
        conn.sendall(b"".join(hand_scan(k, 60)[:24 + 44 + 10 * 20] for k in range(3, 11)) + hand_scan(11, 60))
        wait_for(lambda: scans)
        assert [s.scan_number for s in scans] == [11]
        wait_for(lambda: len(reports) >= 2, 5.0)
        time.sleep(1.5)  # nothing more is pending: no further report
    finally:
        client.close()
        if conn is not None:
            conn.close()
        server.close()
    assert client.parser.cut_short == 10 and client.refusals.total == 10 and client.bad_scans == 10
    assert len(reports) == 2, reports
    assert "LD-MRS: message dropped (cut short" in reports[0][1]
    assert "9 refused in the last" in reports[1][1] and "(10 so far)" in reports[1][1]
    assert reports[1][0] - reports[0][0] >= 0.9
