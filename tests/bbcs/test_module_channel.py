"""The loop's channel input (a module's first stream input is a Zenoh FIFO channel the loop drains and blocks on),
through a real router: every datum in order under back-pressure, wrong data rejected, and while the loop sits in
the channel's ``recv()`` the tick, the heartbeat, ``call_soon`` from another thread and ``request_stop`` still
reach it (each wakes it with a session-local sample that never reaches a handler)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Annotated

import msgspec
import pytest

from bbcs import keys
from bbcs.context import ModuleContext
from bbcs.errors import BusErrorCode
from bbcs.module import Heartbeat, Module
from bbcs.session import local_client
from bbcs.slots import InputSlot, Kind, OutputSlot, Publisher
from bbcs.testing import wait_alive, wait_until


class Item(msgspec.Struct, frozen=True, kw_only=True):
    seq: int
    level: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.5


class Err(msgspec.Struct, frozen=True):
    code: int


class Slow(Module):
    """A stream input with a small queue and a slow handler (back-pressure), a tick, and an error slot."""

    name = "slow"
    slots = (InputSlot("items", Item, kind=Kind.STREAM, queue=8, peer="feeder"),
             OutputSlot("error", Err, kind=Kind.STREAM))
    error_slot = "error"
    tick_period = 0.05

    def on_start(self) -> None:
        self.got: list[int] = []
        self.ticks = 0
        self.calls: list[str] = []
        self.threads: set[int] = set()

    def on_items(self, msg: Item) -> None:
        self.threads.add(threading.get_ident())
        if msg.seq % 100 == 0:
            time.sleep(0.002)
        self.got.append(msg.seq)

    def on_tick(self) -> None:
        self.threads.add(threading.get_ident())
        self.ticks += 1


def _beat_seq(sample) -> int:  # noqa: ANN001
    return msgspec.msgpack.decode(sample.payload.to_bytes(), type=Heartbeat).seq


@pytest.fixture
def slow(router: int) -> Iterator[tuple[Slow, threading.Thread]]:
    mod = Slow(ModuleContext(robot="r1", module="slow", bus=local_client(router)))
    loop = threading.Thread(target=mod.run, name="slow-loop", daemon=True)
    loop.start()
    try:
        yield mod, loop
    finally:
        mod.request_stop()
        loop.join(20)



def test_the_stream_input_is_the_loops_channel(slow, sessions) -> None:
    mod, _ = slow
    wait_alive(sessions(), "r1", "slow")
    assert mod._channel_reader is not None and mod._channel_reader.spec.name == "items"
    assert mod._channel_reader.chan is not None


def test_every_datum_in_order_under_back_pressure_and_wrong_data_rejected(slow, sessions) -> None:
    mod, loop = slow
    s = sessions()
    wait_alive(s, "r1", "slow")
    errors: list[int] = []
    decode_err = msgspec.msgpack.Decoder(Err).decode
    err_sub = s.declare_subscriber(keys.slot_key("r1", "slow", "error"),
                                   lambda smp: errors.append(decode_err(smp.payload.to_bytes()).code))
    pub = Publisher(s, keys.slot_key("r1", "feeder", "items"), InputSlot("items", Item, kind=Kind.STREAM))
    wait_until(lambda: mod.ticks > 0, 10, "the first tick")
    n = 3000
    for seq in range(n):
        pub.publish(Item(seq=seq))
    pub.publish_raw(msgspec.msgpack.encode({"seq": n, "level": 7.0}))   # out of range
    pub.publish_raw(b"\x93garbage")                                      # malformed
    pub.publish(Item(seq=n + 1))
    wait_until(lambda: len(mod.got) >= n + 1, 60, "every datum handled")
    wait_until(lambda: len(errors) >= 2, 10, "two error reports")
    assert mod.got == [*range(n), n + 1]                  # none lost, none doubled, in order; no wake sample
    assert errors == [BusErrorCode.OUT_OF_RANGE, BusErrorCode.MALFORMED] and mod.rejected == 2
    assert mod.threads == {loop.ident}                    # handlers and ticks on the loop's thread only
    pub.close()
    err_sub.undeclare()


def test_an_idle_loop_ticks_beats_runs_call_soon_and_stops(slow, sessions) -> None:
    mod, loop = slow
    s = sessions()
    beats: list[int] = []
    hb = s.declare_subscriber(keys.heartbeat_key("r1", "slow"), lambda smp: beats.append(_beat_seq(smp)))
    wait_alive(s, "r1", "slow")
    wait_until(lambda: mod._blocked_on is not None, 10, "the loop blocked on its channel")
    ticks = mod.ticks
    wait_until(lambda: mod.ticks >= ticks + 10, 10, "ten ticks with no input at all")
    wait_until(lambda: len(beats) >= 2, 10, "two heartbeats from an idle loop")

    ran = threading.Event()
    where: list[int] = []
    threading.Thread(target=lambda: mod.call_soon(lambda: (where.append(threading.get_ident()), ran.set()))).start()
    assert ran.wait(5), "call_soon never ran on an idle loop"
    assert where == [loop.ident]
    assert mod.got == [] and mod.rejected == 0            # the wake samples reached no handler

    t0 = time.monotonic()
    threading.Thread(target=mod.request_stop).start()
    loop.join(10)
    assert not loop.is_alive(), "request_stop did not end an idle loop"
    assert time.monotonic() - t0 < 5
    hb.undeclare()


def test_a_steady_trickle_still_lets_ticks_heartbeats_and_call_soon_through(slow, sessions) -> None:
    """Data that each arrive while the loop is blocked are handled in its short idle cycle (block, handle, block);
    the timer's deadline and the loop's queue still pull it out of that cycle: ticks and heartbeats keep their
    pace and ``call_soon`` runs, in between the data."""
    mod, loop = slow
    s = sessions()
    beats: list[int] = []
    hb = s.declare_subscriber(keys.heartbeat_key("r1", "slow"), lambda smp: beats.append(_beat_seq(smp)))
    wait_alive(s, "r1", "slow")
    pub = Publisher(s, keys.slot_key("r1", "feeder", "items"), InputSlot("items", Item, kind=Kind.STREAM))
    wait_until(lambda: mod._blocked_on is not None, 10, "the loop blocked on its channel")
    ticks, n_beats = mod.ticks, len(beats)
    ran: list[int] = []
    t0 = time.monotonic()
    seq = 1
    while time.monotonic() - t0 < 2.5:          # one datum every ~2 ms: each finds the loop idle
        pub.publish(Item(seq=seq))
        if seq % 200 == 0:
            mod.call_soon(lambda n=seq: ran.append(n))
        seq += 1
        time.sleep(0.002)
    wait_until(lambda: len(mod.got) >= seq - 1, 10, "every datum of the trickle handled")
    assert mod.got == list(range(1, seq))
    assert mod.ticks - ticks >= 20, f"{mod.ticks - ticks} ticks in 2.5 s at a 50 ms period"
    assert len(beats) - n_beats >= 2, "the heartbeat stopped under a trickle of data"
    wait_until(lambda: len(ran) == (seq - 1) // 200, 5, "every call_soon run")
    assert ran == sorted(ran)
    pub.close()
    hb.undeclare()
