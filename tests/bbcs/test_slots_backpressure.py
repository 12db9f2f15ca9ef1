"""A safe slot's publisher says when a consumer holds it back: a module whose handler is stuck fills its safe queue,
Zenoh stops reading the link, and the publisher's ``put`` blocks; ``backpressure_events`` counts it (and the log
names the slot). Once the handler goes on, every datum arrives, in order. The control: the same data to a
consumer that keeps up count no back-pressure."""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator

import msgspec
import pytest

from bbcs import keys
from bbcs.context import ModuleContext
from bbcs.module import Module
from bbcs.session import local_client
from bbcs.slots import InputSlot, Kind, OutputSlot, Publisher
from bbcs.testing import wait_alive, wait_until

BLOB = 64 * 1024


class Blob(msgspec.Struct, frozen=True, kw_only=True):
    seq: int
    body: bytes


class Held(Module):
    """A stream input with a small queue whose handler waits for ``go`` before the first datum."""

    name = "held"
    slots = (InputSlot("blobs", Blob, kind=Kind.STREAM, queue=4, peer="feeder"),)

    def on_start(self) -> None:
        self.go = threading.Event()
        self.got: list[int] = []

    def on_blobs(self, msg: Blob) -> None:
        self.go.wait(60)
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


def _feed(pub: Publisher[Blob], n: int | None = None) -> tuple[threading.Thread, threading.Event]:
    """Publish blobs 0, 1, … in a thread: ``n`` of them, or until the returned event is set."""
    body = b"b" * BLOB
    stop = threading.Event()

    def run() -> None:
        seq = 0
        while not stop.is_set() and (n is None or seq < n):
            pub.publish(Blob(seq=seq, body=body))
            seq += 1

    feeder = threading.Thread(target=run, daemon=True)
    feeder.start()
    return feeder, stop



def test_a_stuck_consumer_is_reported_by_the_publisher_and_loses_nothing(held: Held, sessions, caplog) -> None:
    s = sessions()
    wait_alive(s, "r1", "held")
    pub = Publisher(s, keys.slot_key("r1", "feeder", "blobs"), OutputSlot("blobs", Blob, kind=Kind.STREAM))
    with caplog.at_level(logging.WARNING, logger="bbcs.slots"):
        # until the queue, the router's queues and the sockets' buffers are full (some tens of MB) and a put blocks
        feeder, stop = _feed(pub)
        wait_until(lambda: pub.backpressure_events >= 1, 60, "the publisher reporting back-pressure")
        assert feeder.is_alive() and pub._putting, "the put is still blocked: nothing was dropped to make room"
        stop.set()
        held.go.set()
        feeder.join(60)
    assert not feeder.is_alive()
    n = pub.published
    wait_until(lambda: len(held.got) >= n, 60, "every blob handled")
    assert held.got == list(range(n)), "none lost, none doubled, in order"
    assert pub.backpressure_events >= 1  # more if a put also blocked a while as the buffers filled (a loaded machine)
    assert any("back-pressure" in r.getMessage() and "feeder/blobs" in r.getMessage() for r in caplog.records)
    pub.close()


def test_control_a_consumer_that_keeps_up_causes_no_report(held: Held, sessions) -> None:
    held.go.set()
    s = sessions()
    wait_alive(s, "r1", "held")
    pub = Publisher(s, keys.slot_key("r1", "feeder", "blobs"), OutputSlot("blobs", Blob, kind=Kind.STREAM))
    feeder, _ = _feed(pub, 40)
    feeder.join(30)
    wait_until(lambda: len(held.got) >= 40, 30, "every blob handled")
    assert held.got == list(range(40)) and pub.backpressure_events == 0
    pub.close()


class PutState:
    """What the watcher reads of a publisher: puts done, one in progress, reports."""

    def __init__(self) -> None:
        self.key = "cromat/r1/feeder/blobs"
        self.published = 0
        self._putting = False
        self.backpressure_events = 0


def test_the_watcher_reports_a_put_blocked_three_looks_once_and_a_moving_stream_never() -> None:
    from bbcs.slots import _BlockWatch

    watch, blocked, moving = _BlockWatch(), PutState(), PutState()
    blocked._putting = moving._putting = True
    for _ in range(6):  # six looks, 25 ms apart in the thread: the same put in progress the whole time
        moving.published += 1  # a put in progress at each look, but each time another one
        watch.look([blocked, moving])
    assert blocked.backpressure_events == 1 and moving.backpressure_events == 0
    blocked.published, blocked._putting = 1, False  # it went through
    watch.look([blocked])
    blocked._putting = True  # the next put: two looks only, then it goes through
    watch.look([blocked])
    watch.look([blocked])
    blocked.published, blocked._putting = 2, False
    watch.look([blocked])
    assert blocked.backpressure_events == 1
