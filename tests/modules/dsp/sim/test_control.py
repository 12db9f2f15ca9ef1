"""The simulator's control port (modules/dsp/sim/control.py): a telemetry frame spoilt on request, with a good CRC,
exactly as many as asked; bad commands refused with the reason; loopback only."""

from __future__ import annotations

import math
import select
import subprocess
import threading

import pytest

from bbcs.contracts import dsp as p
from bbcs.net import free_port
from bbcs.testing import wait_until
from modules.dsp.link import DspLink
from modules.dsp.refusals import Refusal
from modules.dsp.sim.control import ControlPort, Spoil, main, parse_command, send_command
from modules.dsp.sim.faults import BadTelemetry

FRAME = p.Telemetry(time_ms=5, position=p.TelPosition(lat=37.4, lon=-6.0, alt=20.0), heading=10.0,
                    status=p.DspStatus(mode=0, tracking=True, path_valid=True, airborne=True, queue_length=3))


def test_commands_parse_or_say_what_is_wrong() -> None:
    assert parse_command("spoil position.lat=200") == Spoil("position.lat", 200.0, 1)
    nan = parse_command("  spoil heading=nan 3 ")
    assert isinstance(nan, Spoil) and nan.path == "heading" and math.isnan(nan.value) and nan.count == 3
    assert parse_command("spoil status.mode=9") == Spoil("status.mode", 9, 1)
    assert parse_command("spoil status.reserved_flags=0x08") == Spoil("status.reserved_flags", 8, 1)
    assert parse_command("pending") == "pending"
    for text, match in (("", "empty"), ("fly", "unknown command"), ("spoil position.lat", "unknown command"),
                        ("spoil position.latitude=1", "no telemetry field"), ("spoil time_ms=1", "no telemetry"),
                        ("spoil status.tracking=1", "not a number"), ("spoil status.mode=nine", "an integer"),
                        ("spoil status.queue_length=70000", "does not fit"), ("spoil heading=1 0", "COUNT"),
                        ("spoil heading=x", "a number")):
        with pytest.raises(ValueError, match=match):
            parse_command(text)


def test_the_port_spoils_exactly_the_frames_asked_for_and_answers_every_command() -> None:
    telemetry = BadTelemetry(every=0)
    port = ControlPort("127.0.0.1", 0, telemetry)
    try:
        assert send_command("127.0.0.1", port.port, "spoil position.lat=200 2") == "ok spoil position.lat=200.0 x2"
        assert send_command("127.0.0.1", port.port, "spoil pan_tilt.mode=5").startswith("ok")
        assert send_command("127.0.0.1", port.port, "spoil nothing=1").startswith("error: no telemetry field")
        assert send_command("127.0.0.1", port.port, "pending") == "ok pending 3 injected 0"
    finally:
        port.close()
    spoilt = [telemetry.spoil(FRAME) for _ in range(4)]
    assert [s.position.lat if s is not None else None for s in spoilt] == [200.0, 200.0, None, None]  # type: ignore[union-attr]
    assert telemetry.pending == 1  # pan_tilt.mode waits for a frame that carries pan & tilt
    with_pt = p.Telemetry(time_ms=6, pan_tilt=p.PanTiltState(mode=0, pan=0.0, tilt=0.0))
    assert telemetry.spoil(with_pt).pan_tilt.mode == 5  # type: ignore[union-attr]
    assert telemetry.pending == 0 and telemetry.injected == telemetry.sent == 3


def test_the_port_listens_on_loopback_only() -> None:
    with pytest.raises(ValueError, match="loopback only"):
        ControlPort("10.1.2.3", 0, BadTelemetry(every=0))


def test_one_frame_spoilt_through_the_simulators_option_is_refused_by_the_link(processes) -> None:
    """``python -m modules.dsp.sim --control``: one frame with latitude 200° and a good CRC, the frames around it
    good; the real link refuses that one frame and no other."""
    control = free_port()  # a TCP port free now; the UDP one of the same number is as good a guess
    proc = processes.start(["-m", "modules.dsp.sim", "--tcp", "127.0.0.1:0", "--time-scale", "4",
                            "--control", f"127.0.0.1:{control}"], stdout=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 15.0)
    assert ready, "the simulator printed nothing"
    url = proc.stdout.readline().strip()
    good: list[p.Telemetry] = []
    refused: list[Refusal] = []
    lock = threading.Lock()

    def on_good(t: p.Telemetry) -> None:
        with lock:
            good.append(t)

    with DspLink(url, on_telemetry=on_good, on_refused=refused.append) as link:
        link.send(p.SetTelemetryMask(mask=int(p.TelemetryField.POSITION | p.TelemetryField.STATUS)))
        link.send(p.SetStateTransmission(enable=True, period_ms=20))
        wait_until(lambda: len(good) > 10, what="good telemetry")
        assert main([f"127.0.0.1:{control}", "spoil", "position.lat=200"]) == 0
        wait_until(lambda: len(refused) == 1, what="the spoilt frame refused")
        with lock:
            before = len(good)
        wait_until(lambda: len(good) > before + 20, what="good frames after it")
        stats = link.stats()
    assert [r.field for r in refused] == ["position.lat"] and "=200.0 is out of range" in refused[0].detail
    assert stats.telemetry_refused == 1
    assert all(abs(t.position.lat) <= 90 for t in good)  # type: ignore[union-attr]
    assert send_command("127.0.0.1", control, "pending") == "ok pending 0 injected 1"
