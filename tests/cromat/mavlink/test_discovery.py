"""``cromat mavlink --all`` (a process) on a real router: robots become MAVLink systems as their GRI states appear,
each with the lowest free system id (a fixed ``--robot NAME=ID`` kept for its robot), and the gateway's GRI
heartbeats name the robots only while a MAVLink ground station is heard.

The robots here are GRI state publishers on the router (what a RAL publishes, at its 5 Hz) and the ground-station
heartbeats are read off the bus as a RAL reads them: the gateway's side of both is the real one. The MAVLink client
is pymavlink's.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest
import zenoh

from bbcs import wire
from bbcs.contracts import gri
from bbcs.contracts.geo import GeoPoint
from bbcs.contracts.robot import RobotTelemetry
from bbcs.session import local_client, open_session
from bbcs.testing import free_port, wait_until

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mavlink_support import GatewayProcess, Mav  # noqa: E402

pytestmark = pytest.mark.timeout(120)


def position(i: int) -> GeoPoint:
    return GeoPoint(lat=37.41 + 0.001 * i, lon=-6.0 - 0.001 * i, alt=20.0 + i)


class Robots:
    """GRI states of the robots started so far, each every 0.2 s, on the router; GCS heartbeats as heard."""

    def __init__(self, port: int) -> None:
        self.session = open_session(local_client(port))
        self.pubs: dict[str, object] = {}
        self.lock = threading.Lock()
        self.beats: list[tuple[float, str, list[str]]] = []
        self.stop = threading.Event()
        self.sub = self.session.declare_subscriber(gri.gcs_heartbeat_key("*"), self._on_beat)
        self.thread = threading.Thread(target=self._publish, daemon=True)
        self.thread.start()

    def _on_beat(self, sample: zenoh.Sample) -> None:
        try:
            beat = gri.decode_heartbeat(sample.payload.to_bytes())
        except msgspec.MsgspecError:
            return
        with self.lock:
            self.beats.append((time.monotonic(), beat.gcs, list(beat.robots)))

    def named(self, since: float) -> set[str]:
        """Robots the gateway's heartbeats named after ``since``."""
        with self.lock:
            return {r for t, gcs, robots in self.beats if t >= since and gcs == "mavlink" for r in robots}

    def last_named(self) -> list[str] | None:
        with self.lock:
            return next((robots for _, gcs, robots in reversed(self.beats) if gcs == "mavlink"), None)

    def start(self, name: str) -> None:
        pub = self.session.declare_publisher(gri.state_key(name), encoding=wire.encoding_for(gri.GriState))
        with self.lock:
            self.pubs[name] = pub

    def _publish(self) -> None:
        while not self.stop.is_set():
            with self.lock:
                pubs = list(self.pubs.items())
            for i, (name, pub) in enumerate(pubs):
                tel = RobotTelemetry(stamp=time.time(), position=position(i), airborne=False)
                state = gri.GriState(robot=name, kind="uquad", stamp=time.time(), telemetry=tel, manager_up=True)
                pub.put(gri.encode(state))  # type: ignore[attr-defined]
            self.stop.wait(0.2)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(2.0)
        self.sub.undeclare()
        self.session.close()


@pytest.fixture
def robots(router: int) -> Iterator[Robots]:
    r = Robots(router)
    try:
        yield r
    finally:
        r.close()


def test_robots_become_systems_as_they_appear_and_the_link_follows_the_ground_station(
        router: int, robots: Robots) -> None:
    robots.start("alpha")
    tcp = free_port()
    gw = GatewayProcess("--connect", f"tcp/127.0.0.1:{router}", "--all", "--robot", "gamma=7", "--tcp", str(tcp),
                        "--udp", "127.0.0.1:9", "-v")  # UDP to the discard port: nobody listens there
    mav = qgc = None
    try:
        gw.wait_line("serving on", 30)
        mav = Mav(tcp)  # reads; sends no heartbeat
        mav.wait(0, "HEARTBEAT", sysid=1, timeout_s=20)
        gw.wait_line("robot alpha is MAVLink system 1")
        # robots that appear later: the next free id; gamma keeps the id it was given
        robots.start("beta")
        mav.wait(0, "HEARTBEAT", sysid=2, timeout_s=20)
        robots.start("gamma")
        beat = mav.wait(0, "HEARTBEAT", sysid=7, timeout_s=20)
        assert beat.type == 2  # MAV_TYPE_QUADROTOR: a uquad
        assert {m.get_srcSystem() for m in mav.since(0, "HEARTBEAT")} == {1, 2, 7}
        at = mav.mark()
        pos = mav.wait(at, "GLOBAL_POSITION_INT", sysid=2, timeout_s=10)
        assert (round(pos.lat / 1e7, 5), round(pos.lon / 1e7, 5), round(pos.alt / 1000)) == (37.411, -6.001, 21)

        # no MAVLink ground station heard yet: the robots are served but not linked (no heartbeat names them)
        time.sleep(2.0)
        assert robots.named(0.0) == set()
        qgc = Mav(tcp, sysid=251, heartbeats=True)
        wait_until(lambda: sorted(robots.last_named() or []) == ["alpha", "beta", "gamma"], 15,
                   "the gateway's heartbeats naming every robot")
        # quiet: within --gcs-timeout (3 s) they stop naming the robots, the liveliness token stays
        qgc.quiet()
        quiet_at = time.monotonic()
        wait_until(lambda: robots.last_named() == [], 10, "heartbeats naming no robot")
        released = time.monotonic() - quiet_at
        assert 2.0 <= released <= 6.0, released
        gw.wait_line("link to beta released")
        later = time.monotonic()
        time.sleep(1.5)
        assert robots.named(later) == set()
    finally:
        for c in (qgc, mav):
            if c is not None:
                c.close()
        gw.close()
