"""The simulator as its own process on a real pty / TCP port, driven through the real DspLink.

Stated tolerance for the flown path: the simulated aircraft passes within 2.0 m (3-D) of every waypoint as
transmitted (lat/lon on the 1e-4 degree grid); the DSP's acceptance radius is 1.5 m horizontal, 1.0 m
vertical.
"""

from __future__ import annotations

import json
import math
import select
import subprocess
import threading
from pathlib import Path

import pytest

from bbcs.contracts import dsp as p
from bbcs.geodesy import LocalFrame
from bbcs.testing import wait_until
from modules.dsp import codec
from modules.dsp.config import load_dsp_config
from modules.dsp.errors import DspTimeout
from modules.dsp.link import DspLink, startup, startup_commands
from modules.dsp.sim.cli import main

from ..conftest import UAV1

HOME = (37.4117, -6.0025, 12.0)
TOLERANCE_M = 2.0
FRAME = LocalFrame(*HOME)
"""The simulator's frame at home (bbcs.geodesy)."""


def local(lat: float, lon: float, alt: float) -> tuple[float, float, float]:
    """North, east, up metres from home."""
    east, north, up = FRAME.to_local(lat, lon, alt)
    return north, east, up


def start_sim(processes, *args: str) -> tuple[subprocess.Popen, str]:
    proc = processes.start(["-m", "modules.dsp.sim", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 15.0)
    assert ready, "the simulator printed nothing"
    line = proc.stdout.readline().strip()
    assert line, f"simulator exited: {proc.stderr.read() if proc.poll() is not None else ''}"
    return proc, line


class Recorder:
    """Collects telemetry from the link's reader thread."""

    def __init__(self) -> None:
        self.frames: list[p.Telemetry] = []
        self.lock = threading.Lock()

    def __call__(self, t: p.Telemetry) -> None:
        with self.lock:
            self.frames.append(t)

    @property
    def last(self) -> p.Telemetry | None:
        with self.lock:
            return self.frames[-1] if self.frames else None


def fly_startup(url: str, recorder: Recorder) -> DspLink:
    conf = load_dsp_config(UAV1, port=url)
    # a clean line: a generous ack timeout keeps a slow (loaded) simulator process from failing the start-up
    link = DspLink(conf.port, conf.baudrate, ack_timeout=1.0, on_telemetry=recorder)
    try:
        startup(link, conf)
    except BaseException:
        link.close()
        raise
    return link


def take_off(link: DspLink, rec: Recorder) -> None:
    link.send(p.SetMode(mode=p.Mode.TAKE_OFF))
    wait_until(lambda: rec.last is not None and rec.last.position.alt > HOME[2] + 9.7,
               what="take-off to 10 m", deadline_s=30)


def follow_paths(link: DspLink, rec: Recorder, speed: float) -> None:
    """Airborne in mode 0 with tracking on at ``speed``: what a waypoint test starts from."""
    take_off(link, rec)
    link.send(p.SetMode(mode=p.Mode.PATH_AUTO_HEADING))
    link.send(p.SetTracking(enable=True))
    link.send(p.SetSpeed(speed=speed))


def test_startup_sequence_arrives_in_spec_order(processes, tmp_path: Path) -> None:
    record = tmp_path / "commands.jsonl"
    _, url = start_sim(processes, "--pty", "--record", str(record))
    assert url.startswith("/dev/")
    rec = Recorder()
    link = fly_startup(url, rec)
    link.close()
    conf = load_dsp_config(UAV1)
    lines = [json.loads(line) for line in record.read_text().splitlines()]
    expected = startup_commands(conf)
    assert [r["name"] for r in lines] == [codec.message_name(c.MSG_ID) for c in expected]
    assert [r["id"] for r in lines] == [int(c.MSG_ID) for c in expected]
    assert all(r["status"] == 0 and not r["duplicate"] for r in lines)
    assert lines[0]["fields"]["speed"] == 0.0
    assert lines[1]["fields"]["mask"] == conf.telemetry_mask
    assert lines[2]["fields"]["enable"] is True
    assert lines[4]["fields"]["enable"] is False
    assert lines[6]["fields"]["heli_type"] == int(conf.heli_type)
    assert [r["fields"]["axis"] for r in lines[7:]] == [int(g.axis) for g in conf.pid_groups]
    assert [r["t"] for r in lines] == sorted(r["t"] for r in lines)


def test_waypoint_list_is_flown_in_mode_0(processes) -> None:
    _, url = start_sim(processes, "--pty", "--time-scale", "25")
    rec = Recorder()
    link = fly_startup(url, rec)
    try:
        follow_paths(link, rec, 6.0)
        offsets = [(50, 0, 25), (50, 50, 30), (0, 50, 30), (-30, 20, 20)]
        sent = [p.AddWaypoint(lat=FRAME.to_geo(e, n)[0], lon=FRAME.to_geo(e, n)[1], alt=alt + 0.0)
                for n, e, alt in offsets]
        start = len(rec.frames)
        assert link.send_waypoints(sent) == 4
        wait_until(lambda: any(t.status.queue_length == 4 for t in rec.frames[start:]), what="the path queued")
        wait_until(lambda: rec.last.status.queue_length == 0 and rec.last.nav.distance < 0,
                   what="the path flown", deadline_s=60)
    finally:
        link.close()
    flight = rec.frames[start:]
    assert max(t.speed.ground for t in flight) <= 6.0 + 1e-3  # never above the commanded speed
    closest: list[tuple[float, int]] = []
    for wp in sent:
        q = codec.decode_payload(p.MsgId.ADD_WAYPOINT, codec.encode_payload(wp))  # as transmitted
        target = local(q.lat, q.lon, q.alt)  # type: ignore[attr-defined]
        dists = [math.dist(target, local(t.position.lat, t.position.lon, t.position.alt)) for t in flight]
        best = min(range(len(dists)), key=dists.__getitem__)
        closest.append((dists[best], best))
    print("\nclosest approach to each waypoint (m):", [round(d, 2) for d, _ in closest])
    assert all(d <= TOLERANCE_M for d, _ in closest)
    assert [i for _, i in closest] == sorted(i for _, i in closest)  # in order
    queue_lengths = [t.status.queue_length for t in flight]
    assert max(queue_lengths) == 4 and queue_lengths[-1] == 0


def test_abort_empties_the_queue(processes, tmp_path: Path) -> None:
    record = tmp_path / "commands.jsonl"
    _, url = start_sim(processes, "--pty", "--time-scale", "20", "--record", str(record))
    rec = Recorder()
    link = fly_startup(url, rec)
    try:
        follow_paths(link, rec, 8.0)
        far = [p.AddWaypoint(lat=HOME[0] + 0.002 * (i + 1), lon=HOME[1], alt=40.0) for i in range(5)]
        link.send_waypoints(far)
        wait_until(lambda: rec.last.speed.ground > 3.0 and rec.last.status.queue_length == 5, what="flying the path")
        assert link.abort().ok
        wait_until(lambda: rec.last.status.queue_length == 0 and not rec.last.status.path_valid, what="empty queue")
        wait_until(lambda: rec.last.speed.ground < 0.2, what="the aircraft stopping", deadline_s=20)
        assert rec.last.nav.distance < 0 and rec.last.status.tracking  # tracking untouched, nothing to track
    finally:
        link.close()
    names = [json.loads(line)["name"] for line in record.read_text().splitlines()]
    assert names[-1] == "ABORT" and names.count("ADD_WAYPOINT") == 5


def test_wrong_baud_times_out_cleanly(processes, tmp_path: Path) -> None:
    record = tmp_path / "commands.jsonl"
    proc, url = start_sim(processes, "--pty", "--baud", "921600", "--record", str(record))
    conf = load_dsp_config(UAV1, port=url)
    with DspLink(url, 115_200, ack_timeout=0.05, retries=2) as link:
        with pytest.raises(DspTimeout, match=r"for SetSpeed .* after 3 attempts"):
            startup(link, conf)
    assert record.read_text() == ""  # the DSP understood nothing
    assert proc.poll() is None


def test_tcp_prints_the_url_and_serves(processes) -> None:
    _, url = start_sim(processes, "--tcp", "127.0.0.1:0")
    assert url.startswith("socket://127.0.0.1:") and int(url.rsplit(":", 1)[1]) > 0
    with DspLink(url) as link:
        assert link.ping().ok


def test_fault_injection_on_the_line(processes) -> None:
    _, url = start_sim(processes, "--pty", "--time-scale", "5", "--corrupt", "0.01", "--garbage", "0.05",
                       "--seed", "4")
    conf = load_dsp_config(UAV1, port=url)
    rec = Recorder()
    with DspLink(url, ack_timeout=0.3, retries=10, on_telemetry=rec) as link:
        startup(link, conf)
        wait_until(lambda: len(rec.frames) > 50, what="telemetry through the noise")
        stats = link.stats()
    assert stats.bad_crc > 0 and stats.bytes_discarded > 0
    assert stats.commands_acked == 16


def test_stops_cleanly_on_sigterm(processes) -> None:
    from bbcs.testing import stop_process

    proc, _ = start_sim(processes, "--pty")
    assert stop_process(proc, grace_s=20) == 0


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(SystemExit) as info:
        main(["--tcp", "nowhere"])
    assert info.value.code == 2
    with pytest.raises(SystemExit):
        main(["--corrupt", "2"])
    assert main(["--pty", "--time-scale", "0"]) == 2
