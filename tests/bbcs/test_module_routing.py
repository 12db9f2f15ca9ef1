"""Input switching at run time: A → B while both publish; one clear switch point, none lost, none twice."""

from __future__ import annotations

import json
import sys
import threading
from pathlib import Path

import msgspec

from bbcs import keys
from bbcs.errors import BusErrorCode
from bbcs.routing import RouteAck
from bbcs.slots import OutputSlot, Publisher
from bbcs.testing import stop_process, wait_alive, wait_until

HERE = Path(__file__).resolve().parent
STOP_S = 20.0  # a loaded machine may take seconds to stop a Zenoh process: the exit code is what is checked
sys.path.insert(0, str(HERE))
from probe_module import ProbeControl, ProbeError  # noqa: E402
from probe_support import handled, publisher, records, start_probe  # noqa: E402


class AckWatcher:
    def __init__(self, session) -> None:
        self.acks: list[RouteAck] = []
        self.errors: list[int] = []
        self.cond = threading.Condition()
        dec = msgspec.msgpack.Decoder(RouteAck).decode
        edec = msgspec.msgpack.Decoder(ProbeError).decode

        def on_ack(sample) -> None:
            with self.cond:
                self.acks.append(dec(sample.payload.to_bytes()))
                self.cond.notify_all()

        self.subs = [session.declare_subscriber(keys.route_ack_key("r1", "probe"), on_ack),
                     session.declare_subscriber(keys.slot_key("r1", "probe", "error"),
                                                lambda s: self.errors.append(edec(s.payload.to_bytes()).error_probe))]

    def wait(self, count: int) -> RouteAck:
        with self.cond:
            assert self.cond.wait_for(lambda: len(self.acks) >= count, 20), "no route acknowledgement"
            return self.acks[count - 1]

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()


def test_switch_a_to_b_while_both_publish(processes, router, sessions, tmp_path):
    s = sessions()
    probe, rec = start_probe(processes, router, tmp_path)
    wait_alive(s, "r1", "probe")
    acks = AckWatcher(s)
    control = Publisher(s, keys.slot_key("r1", "probe", "control_entrada"), OutputSlot("c", ProbeControl))
    try:
        publisher(processes, router, keys.slot_key("r1", "pub_a", "datos"), "stream", 200_000, "A", rate=3000)
        publisher(processes, router, keys.slot_key("r1", "pub_b", "datos"), "stream", 200_000, "B", rate=3000)
        control.publish(ProbeControl(slot_entrada_datos=1))
        assert acks.wait(1).routes == {"datos": 1}
        wait_until(lambda: len(handled(rec, "datos")) > 500, 30, "A's data")
        control.publish(ProbeControl(slot_entrada_datos=2))
        ack = acks.wait(2)
        assert ack.accepted and ack.routes == {"datos": 2}
        wait_until(lambda: sum(r["source"] == "B" for r in handled(rec, "datos")) > 500, 30, "B's data")
    finally:
        control.close()
        acks.close()
    assert stop_process(probe, STOP_S) == 0
    rows = records(rec)
    switch = [i for i, r in enumerate(rows) if r.get("event") == "route"]
    assert len(switch) == 2, rows[:5]
    first, second = switch
    before = [r for r in rows[first:second] if r.get("slot") == "datos"]
    after = [r for r in rows[second:] if r.get("slot") == "datos"]
    assert before and {r["source"] for r in before} == {"A"}, "only A before the switch point"
    a_seqs = [r["seq"] for r in before]
    assert a_seqs == list(range(a_seqs[0], a_seqs[0] + len(a_seqs))), "A's data: none lost, none twice"
    assert after and {r["source"] for r in after} == {"B"}, "only B after the switch point"
    b_seqs = [r["seq"] for r in after]
    assert b_seqs == list(range(b_seqs[0], b_seqs[0] + len(b_seqs))), "B's data: none lost, none twice"
    assert json.loads(json.dumps(rows[second]["routes"])) == {"datos": 2}


def test_bad_route_keeps_old_route_and_reports(processes, router, sessions, tmp_path):
    s = sessions()
    probe, rec = start_probe(processes, router, tmp_path, "--route", "datos=1")
    wait_alive(s, "r1", "probe")
    acks = AckWatcher(s)
    control = Publisher(s, keys.slot_key("r1", "probe", "control_entrada"), OutputSlot("c", ProbeControl))
    try:
        control.publish(ProbeControl(slot_entrada_datos=42))
        ack = acks.wait(1)
        assert not ack.accepted and ack.routes == {"datos": 1} and "slot 42" in ack.reason
        wait_until(lambda: acks.errors == [BusErrorCode.ROUTE_UNKNOWN_SLOT], 10, "the route error code")
        publisher(processes, router, keys.slot_key("r1", "pub_a", "datos"), "stream", 50, "A")
        wait_until(lambda: len(handled(rec, "datos")) == 50, 20, "A's data on the kept route")
        control.publish(ProbeControl(slot_entrada_datos=-1))
        assert acks.wait(2).routes == {"datos": -1}
    finally:
        control.close()
        acks.close()
    assert stop_process(probe, STOP_S) == 0
