"""An output's outbox (issue 32: a safety process never blocks on a report): with a consumer that holds the link
back, a plain safe publisher's ``put`` blocks; the same data through an outbox never blocks the caller, what finds
the outbox full is dropped and counted (a count to report once), and what was kept arrives in order once the
consumer goes on. Real router, real module consumer."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import msgspec
import pytest

from bbcs.context import ModuleContext
from bbcs.errors import SlotError
from bbcs.module import Module
from bbcs.session import local_client
from bbcs.slots import Direction, InputSlot, Kind, OutputSlot, Publisher, SlotSpec
from bbcs.testing import wait_until

BLOB = 64 * 1024
N = 400


class Blob(msgspec.Struct, frozen=True, kw_only=True):
    seq: int
    body: bytes


class Report(msgspec.Struct, frozen=True, kw_only=True):
    seq: int


class Held(Module):
    """A stream input with a small queue whose handler waits for ``go`` (it holds the link back), and a report
    input."""

    name = "held"
    slots = (InputSlot("blobs", Blob, kind=Kind.STREAM, queue=4, peer="feeder"),
             InputSlot("reports", Report, kind=Kind.STREAM, peer="reporter"))

    def on_start(self) -> None:
        self.go = threading.Event()
        self.blobs = 0
        self.got: list[int] = []

    def on_blobs(self, msg: Blob) -> None:
        self.go.wait(60)
        self.blobs += 1

    def on_reports(self, msg: Report) -> None:
        self.got.append(msg.seq)


@pytest.fixture
def held(router: int) -> Iterator[Held]:
    mod = Held(ModuleContext(robot="r1", module="held", bus=local_client(router)))
    loop = threading.Thread(target=mod.run, name="held-loop", daemon=True)
    loop.start()
    try:
        wait_until(lambda: getattr(mod, "_running", False), 20, "the module running")
        yield mod
    finally:
        if hasattr(mod, "go"):
            mod.go.set()
        mod.request_stop()
        loop.join(20)


def test_reports_through_an_outbox_never_block_where_a_plain_put_does(held: Held, sessions) -> None:
    s = sessions()
    feeder = Publisher(s, "cromat/r1/feeder/blobs", OutputSlot("blobs", Blob, kind=Kind.STREAM))
    stop = threading.Event()

    def feed() -> None:  # until the held queue, the router's queues and the sockets are full and a put blocks
        seq = 0
        while not stop.is_set():
            feeder.publish(Blob(seq=seq, body=bytes(BLOB)))
            seq += 1

    feeding = threading.Thread(target=feed, daemon=True)
    feeding.start()
    wait_until(lambda: feeder.backpressure_events >= 1, 60, "a plain safe put blocked (the control)")
    assert feeding.is_alive() and feeder._putting

    reports = Publisher(s, "cromat/r1/reporter/reports", OutputSlot("reports", Report, kind=Kind.STREAM,
                                                                    outbox=16))
    slowest, start = 0.0, time.monotonic()
    for i in range(N):  # on the same blocked link
        t = time.monotonic()
        reports.publish(Report(seq=i))
        slowest = max(slowest, time.monotonic() - t)
    took = time.monotonic() - start
    assert took < 1.0 and slowest < 0.05, f"{N} reports took {took:.2f} s, the slowest {slowest * 1000:.0f} ms"
    assert reports.waiting() == 16 and reports.dropped == N - 16
    assert reports.take_dropped() == N - 16 and reports.take_dropped() == 0, "a count to report once"

    stop.set()
    held.go.set()
    feeding.join(60)
    wait_until(lambda: len(held.got) == 16, 60, "the reports kept, at the consumer")
    assert held.got == list(range(16)), "in order, the oldest kept"
    reports.close()
    feeder.close()


def test_an_outbox_is_a_bound_on_an_output() -> None:
    with pytest.raises(SlotError, match="outbox"):
        SlotSpec("x", Blob, Direction.IN, outbox=4)
    with pytest.raises(SlotError, match="outbox"):
        OutputSlot("x", Blob, outbox=-1)
    with pytest.raises(SlotError, match="outbox"):
        InputSlot("x", Blob).__class__("x", Blob, Direction.IN, outbox=1)
