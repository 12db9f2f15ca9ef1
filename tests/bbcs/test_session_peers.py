"""Peer links (``[bus] links = "peers"``): modules linked directly keep the delivery guarantees of the router path.

Real Zenoh, a real ``cromat router`` on a free port, peers listening on ``127.0.0.1:0`` with multicast off: they
learn each other from the router's gossip and link directly (checked with ``info.peers_zid()``).
"""

from __future__ import annotations

import itertools
import sys
import threading
from pathlib import Path

import msgspec
import zenoh

from bbcs import keys
from bbcs.session import open_session, peer_links_config, zenoh_config
from bbcs.slots import OutputSlot, Publisher
from bbcs.testing import stop_process, wait_alive, wait_until

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from probe_module import ProbeMsg  # noqa: E402
from probe_support import handled, start_probe  # noqa: E402

QOS = {"reliability": zenoh.Reliability.RELIABLE, "congestion_control": zenoh.CongestionControl.BLOCK}


def test_peer_config_listens_on_loopback_only_and_links_only_to_peers() -> None:
    conf = zenoh_config(peer_links_config(7447, 0))
    assert msgspec.json.decode(conf.get_json("mode")) == "peer"
    assert msgspec.json.decode(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:0"]
    assert msgspec.json.decode(conf.get_json("scouting/multicast/enabled")) is False
    # a module never links to a router it learns by gossip (another robot's): only to its own, by its endpoint
    assert msgspec.json.decode(conf.get_json("scouting/gossip"))["autoconnect"]["peer"] == ["peer"]


def test_safe_slot_over_a_direct_link_loses_nothing(processes, router, tmp_path) -> None:
    """A slow consumer (0.2 ms per datum) of a safe slot, its publisher linked to it directly: all, once, in order."""
    n = 5000
    bus = msgspec.json.encode(peer_links_config(router, 0)).decode()
    probe, rec = start_probe(processes, router, tmp_path, "--bus", bus, delay_ms=0.2)
    s = open_session(peer_links_config(router, 0))
    pub = Publisher(s, keys.slot_key("r1", "probe", "state"), OutputSlot("state", ProbeMsg))
    try:
        wait_alive(s, "r1", "probe")
        wait_until(lambda: bool(s.info.peers_zid()), 30, "a direct link to the probe module")
        for seq in range(n):
            pub.publish(ProbeMsg(seq=seq))
        wait_until(lambda: len(handled(rec, "state")) >= n, 120, f"{n} data handled")
        assert [r["seq"] for r in handled(rec, "state")] == list(range(n)), "every datum once, in order"
        assert stop_process(probe, 20.0) == 0
    finally:
        pub.close()
        s.close()


JOIN_WINDOW = 1000
"""Data published after the subscriber's declaration returned within which a joining reader may see a gap: about
5 ms of this stream. Measured: gaps of 52 to 765 data, all ending at most 42 data after the declaration returned."""


def test_reader_joining_a_running_stream_over_its_direct_link_misses_nothing_after_the_join(router) -> None:
    """A reader that subscribes to a running stream over its direct link gets it in order, each datum once, and with
    nothing missing once the join is over.

    The join itself is not lossless: data published while the subscription spreads can come in part (a few, then a
    gap), even with the direct link up at both ends (6 joins of 200 under load; docs/bus.md, "Joining a running
    stream"). So the one gap allowed must end within ``JOIN_WINDOW`` data of the declaration."""
    src = open_session(peer_links_config(router, 0))
    sink: zenoh.Session | None = None
    sub = None
    got: list[int] = []
    stop, sent = threading.Event(), [0]
    pub = src.declare_publisher("test/peers/stream", **QOS)

    def run() -> None:
        while not stop.is_set():
            pub.put(str(sent[0]).encode())
            sent[0] += 1
            if sent[0] % 50 == 0:
                stop.wait(0.0002)

    writer = threading.Thread(target=run)
    writer.start()
    try:
        wait_until(lambda: sent[0] > 1000, 30, "the stream to run")
        sink = linked = open_session(peer_links_config(router, 0))
        wait_until(lambda: src.zid() in linked.info.peers_zid() and linked.zid() in src.info.peers_zid(), 30,
                   "the direct link, up at both ends")
        sub = sink.declare_subscriber("test/peers/stream", lambda s: got.append(int(s.payload.to_bytes())))
        mark = sent[0]
        wait_until(lambda: len(got) > 0 and got[-1] > mark + JOIN_WINDOW + 5000, 60, "5000 data after the join")
        stop.set()
        writer.join()
        last = sent[0] - 1
        wait_until(lambda: got[-1] == last, 30, "the last datum")
        assert all(a < b for a, b in itertools.pairwise(got)), "in order, each datum once"
        gaps = [(a, b) for a, b in itertools.pairwise(got) if b != a + 1]
        assert len(gaps) <= 1, f"one gap at most, at the join: {gaps}"
        assert got[0] <= mark + JOIN_WINDOW and all(b <= mark + JOIN_WINDOW for _, b in gaps), (
            f"nothing missing after the join (declared at datum {mark}): first {got[0]}, gaps {gaps}")
    finally:
        stop.set()
        writer.join()
        if sub is not None:
            sub.undeclare()
        pub.undeclare()
        if sink is not None:
            sink.close()
        src.close()
