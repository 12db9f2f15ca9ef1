"""Slot semantics across real processes: safe (none lost, in order), unsafe (newest), late joiner, ranges."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import msgspec
import pytest
import zenoh

from bbcs import keys
from bbcs.errors import BusErrorCode
from bbcs.slots import OutputSlot, Publisher
from bbcs.testing import stop_process, wait_alive, wait_until

HERE = Path(__file__).resolve().parent
STOP_S = 20.0  # a loaded machine may take seconds to stop a Zenoh process: the exit code is what is checked
sys.path.insert(0, str(HERE))
from probe_module import ProbeError, ProbeMsg  # noqa: E402
from probe_support import handled, publisher, records, start_probe  # noqa: E402


@pytest.mark.parametrize("kind,slot,route", [("state", "state", []), ("stream", "datos", ["--route", "datos=1"])])
def test_safe_slot_slow_consumer_loses_nothing(processes, router, sessions, tmp_path, kind, slot, route):
    n = 10_000
    probe, rec = start_probe(processes, router, tmp_path, *route, delay_ms=0.2)
    key = keys.slot_key("r1", "probe", "state") if slot == "state" else keys.slot_key("r1", "pub_a", "datos")
    pub = publisher(processes, router, key, kind, n)
    wait_until(lambda: len(handled(rec, slot)) >= n, 120, f"{n} data handled on {slot}")
    assert pub.stdout.readline().strip() == f"done {n}"
    seqs = [r["seq"] for r in handled(rec, slot)]
    assert seqs == list(range(n)), "every datum once, in order"
    assert stop_process(probe, STOP_S) == 0


def test_unsafe_slot_slow_consumer_sees_newest(processes, router, sessions, tmp_path):
    probe, rec = start_probe(processes, router, tmp_path, delay_ms=5)
    n = 3000
    publisher(processes, router, keys.slot_key("r1", "probe", "fast"), "unsafe", n, final=True)
    wait_until(lambda: any(r["seq"] == n for r in handled(rec, "fast")), 60, "the newest value")
    seqs = [r["seq"] for r in handled(rec, "fast")]
    assert seqs == sorted(set(seqs)), "never an older value after a newer one"
    assert len(seqs) < n, "a slow consumer of an unsafe slot skips stale values"
    assert stop_process(probe, STOP_S) == 0


def test_safe_state_late_joiner_gets_last_value(processes, router, sessions, tmp_path):
    s = sessions()
    pub = Publisher(s, keys.slot_key("r1", "probe", "state"), OutputSlot("state", ProbeMsg))
    try:
        for seq in range(5):
            pub.publish(ProbeMsg(seq=seq))
        probe, rec = start_probe(processes, router, tmp_path)
        wait_until(lambda: handled(rec, "state"), 20, "the cached last value")
        assert [r["seq"] for r in handled(rec, "state")] == [4]
        pub.publish(ProbeMsg(seq=5))
        wait_until(lambda: len(handled(rec, "state")) == 2, 20, "the next live value")
        assert [r["seq"] for r in handled(rec, "state")] == [4, 5]
        assert stop_process(probe, STOP_S) == 0
    finally:
        pub.close()


BAD = [
    (ProbeMsg(seq=1, value=-10.0001), BusErrorCode.OUT_OF_RANGE),
    (ProbeMsg(seq=2, value=10.0001), BusErrorCode.OUT_OF_RANGE),
    (ProbeMsg(seq=3, level=-1), BusErrorCode.OUT_OF_RANGE),
    (ProbeMsg(seq=4, level=3), BusErrorCode.OUT_OF_RANGE),
]


def test_out_of_range_never_reaches_handler(processes, router, sessions, tmp_path):
    s = sessions()
    probe, rec = start_probe(processes, router, tmp_path)
    wait_alive(s, "r1", "probe")
    errors: list[int] = []
    decode = msgspec.msgpack.Decoder(ProbeError).decode
    sub = s.declare_subscriber(keys.slot_key("r1", "probe", "error"),
                               lambda smp: errors.append(decode(smp.payload.to_bytes()).error_probe))
    pub = Publisher(s, keys.slot_key("r1", "probe", "state"), OutputSlot("state", ProbeMsg))
    try:
        for bad, _ in BAD:
            pub.publish(bad)
        pub.publish_raw(b"\xc1 not msgpack")
        pub.publish_raw(msgspec.msgpack.encode({"seq": "one"}))
        # bounds themselves are valid
        pub.publish(ProbeMsg(seq=100, value=-10.0, level=0))
        pub.publish(ProbeMsg(seq=101, value=10.0, level=2))
        wait_until(lambda: len(handled(rec, "state")) == 2 and len(errors) == 6, 20, "2 data and 6 errors")
        assert [r["seq"] for r in handled(rec, "state")] == [100, 101]
        assert errors == [code for _, code in BAD] + [BusErrorCode.MALFORMED, BusErrorCode.MALFORMED]
    finally:
        pub.close()
        sub.undeclare()
    assert stop_process(probe, STOP_S) == 0


def test_sigterm_exits_zero_and_token_disappears(processes, router, sessions, tmp_path):
    s = sessions()
    probe, rec = start_probe(processes, router, tmp_path)
    events: list[zenoh.SampleKind] = []
    sub = s.liveliness().declare_subscriber(keys.alive_key("r1", "probe"), lambda smp: events.append(smp.kind),
                                            history=True)
    try:
        wait_until(lambda: zenoh.SampleKind.PUT in events, 20, "the liveliness token")
        probe.terminate()
        assert probe.wait(STOP_S) == 0
        wait_until(lambda: zenoh.SampleKind.DELETE in events, 20, "the token to disappear")
        assert records(rec)[-1] == {"event": "stop"}
    finally:
        sub.undeclare()


def test_schema_query_lists_slots_with_ranges(processes, router, sessions, tmp_path):
    s = sessions()
    probe, _ = start_probe(processes, router, tmp_path)
    wait_alive(s, "r1", "probe")
    replies = [r.ok for r in s.get(keys.schema_key("r1", "probe"), timeout=20) if r.ok is not None]
    assert len(replies) == 1
    doc = json.loads(replies[0].payload.to_string())
    assert set(doc["slots"]) == {"datos", "state", "fast", "error", "control_entrada"}
    state = doc["slots"]["state"]
    assert (state["direction"], state["kind"], state["safety"]) == ("in", "state", "safe")
    assert doc["slots"]["fast"]["safety"] == "unsafe" and doc["slots"]["datos"]["kind"] == "stream"
    props = state["schema"]["$defs"]["ProbeMsg"]["properties"]
    assert props["value"]["minimum"] == -10.0 and props["value"]["maximum"] == 10.0
    assert props["level"]["exclusiveMaximum"] == 3
    assert doc["control"]["routes"] == {"slot_entrada_datos": "datos"}
    assert stop_process(probe, STOP_S) == 0
