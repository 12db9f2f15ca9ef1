"""Safety first in a module's loop (issue 32): bulk (unsafe) inputs wait while safe work is queued.

The policy as a pure object, then its effect in a real module's loop over a real router: with the loop held busy,
a perception value put first and a safe datum put second are handled safe first."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import msgspec
import pytest

from bbcs.context import ModuleContext
from bbcs.module import Module
from bbcs.priority import SafetyFirst
from bbcs.session import local_client
from bbcs.slots import Direction, InputSlot, Kind, Publisher, Safety, SlotSpec
from bbcs.testing import running, wait_alive, wait_until


def test_one_bulk_item_per_cycle_while_safe_work_waits() -> None:
    order = SafetyFirst[str]()
    for name in ("vision", "lidar", "camera"):
        order.defer(name)
    assert list(order.take(lambda: True)) == ["vision"]  # safe work waiting: one, then back to it
    assert len(order) == 2
    assert list(order.take(lambda: False)) == ["lidar", "camera"]
    assert not order


def test_take_hands_back_only_what_was_set_aside_before_it() -> None:
    order = SafetyFirst[int]()
    order.defer(1)
    order.defer(2)
    got = []
    for item in order.take(lambda: False):
        got.append(item)
        order.defer(item + 10)  # arrives during the cycle: waits for the next one
    assert got == [1, 2]
    assert order.drain() == [11, 12]
    assert order.drain() == []


class Datum(msgspec.Struct, frozen=True):
    n: int


class Busy(Module):
    """A safe input and an unsafe (bulk) one, both callback inputs into the loop's queue."""

    name = "busy"
    slots = (InputSlot("abort", Datum, peer="src"), InputSlot("target", Datum, safety=Safety.UNSAFE, peer="src"))

    def on_start(self) -> None:
        self.handled: list[str] = []

    def on_abort(self, value: Datum) -> None:
        self.handled.append(f"abort {value.n}")

    def on_target(self, value: Datum) -> None:
        self.handled.append(f"target {value.n}")


@pytest.fixture
def busy(router: int) -> Iterator[Busy]:
    with running(Busy(ModuleContext(robot="r1", module="busy", bus=local_client(router)))) as mod:
        yield mod


def test_a_safe_datum_put_after_a_bulk_one_is_handled_first(busy: Busy, sessions) -> None:
    s = sessions()
    wait_alive(s, "r1", "busy")
    safe = Publisher(s, "cromat/r1/src/abort", SlotSpec("abort", Datum, Direction.OUT))
    bulk = Publisher(s, "cromat/r1/src/target", SlotSpec("target", Datum, Direction.OUT, Kind.STATE, Safety.UNSAFE))
    for round_ in range(3):
        hold, held = threading.Event(), threading.Event()
        busy.call_soon(lambda hold=hold, held=held: (held.set(), hold.wait(10)))
        assert held.wait(10), "the loop never ran the call"
        bulk.publish(Datum(round_))  # first into the loop's queue ...
        wait_until(lambda: busy._bbcs_queue.qsize() >= 1, 10, "the target value at the module")
        safe.publish(Datum(round_))  # ... then the safe datum
        wait_until(lambda: busy._bbcs_queue.qsize() >= 2, 10, "the abort datum at the module")
        before = len(busy.handled)
        hold.set()
        wait_until(lambda before=before: len(busy.handled) >= before + 2, 10, "both handled")
        assert busy.handled[before:] == [f"abort {round_}", f"target {round_}"]
