"""The simulator loop on a pty: answers and records every command, flags retransmissions, stops cleanly."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import serial

from bbcs.contracts import dsp as p
from bbcs.testing import wait_until
from modules.dsp import codec
from modules.dsp.framing import FrameParser
from modules.dsp.sim import DspSimulator, PtyEndpoint


def test_records_commands_and_flags_retransmissions(tmp_path: Path) -> None:
    record = tmp_path / "rec.jsonl"
    sim = DspSimulator(PtyEndpoint(), time_scale=10.0, record_path=record).start()
    try:
        parser = FrameParser(codec.DSP_TO_PC_LENGTHS)
        acks: list[p.Ack] = []
        with serial.Serial(sim.endpoint.path, 921_600, timeout=0.05) as port:  # type: ignore[attr-defined]
            wp = codec.encode(p.AddWaypoint(lat=37.5, lon=-6.0, alt=30.0), 9)
            port.write(wp)
            port.write(wp)  # a retransmission: same id, seq and payload
            port.write(codec.encode(p.SetMode(mode=p.Mode.TAKE_OFF), 10))

            def three_acks() -> bool:
                msgs = [codec.decode(f) for f in parser.feed(port.read(4096))]
                acks.extend(m for m in msgs if isinstance(m, p.Ack))
                return len(acks) >= 3

            wait_until(three_acks, what="three acknowledgements")
        assert [(a.acked_id, a.acked_seq, a.status) for a in acks] == [
            (p.MsgId.ADD_WAYPOINT, 9, 0), (p.MsgId.ADD_WAYPOINT, 9, 0),
            (p.MsgId.SET_MODE, 10, p.ErrorCode.NOT_CONFIGURED)]
        assert sim.snapshot().queue_length == 1  # applied once
        rows = [json.loads(line) for line in record.read_text().splitlines()]
        assert [(r["name"], r["duplicate"], r["status_name"]) for r in rows] == [
            ("ADD_WAYPOINT", False, "NONE"), ("ADD_WAYPOINT", True, "NONE"),
            ("SET_MODE", False, "NOT_CONFIGURED")]
        assert rows[0]["fields"] == {"type": "AddWaypoint", "lat": 37.5, "lon": -6.0, "alt": 30.0}
        assert [c.name for c in sim.commands] == [r["name"] for r in rows]
    finally:
        sim.stop()
    sim.stop()  # idempotent
    assert sim.error is None


def test_garbage_on_the_line_is_counted_and_reported() -> None:
    sim = DspSimulator(PtyEndpoint(), time_scale=5.0).start()
    try:
        with serial.Serial(sim.endpoint.path, 921_600, timeout=0.05) as port:  # type: ignore[attr-defined]
            port.write(codec.encode(p.SetTelemetryMask(mask=int(p.TelemetryField.ERROR)), 1))
            port.write(b"\xa5\x5a\x04\x01\x00garbage" * 3 + codec.encode(p.Ping(), 2))
            # the PING may come in a later read than the garbage: wait for it too, then check the list exactly
            wait_until(lambda: sim.rx_stats["bad_crc"] >= 1 and len(sim.commands) >= 2
                       and sim.snapshot().error_code == p.ErrorCode.RX_ERRORS, what="RX_ERRORS latched, PING read")
        assert [c.name for c in sim.commands] == ["SET_TELEMETRY_MASK", "PING"]
    finally:
        sim.stop()


def test_bad_parameters_are_refused_and_an_unstarted_simulator_releases_its_line(tmp_path: Path) -> None:
    ep = PtyEndpoint()
    try:
        with pytest.raises(ValueError):
            DspSimulator(ep, time_scale=0)
    finally:
        ep.close()
    sim = DspSimulator(PtyEndpoint(), record_path=tmp_path / "r.jsonl")
    sim.stop()
    assert sim._closed and sim._record is not None and sim._record.closed
