"""The two-slot FIFO between the scan receiver and the writer (seed Figure 40)."""

from __future__ import annotations

import threading

import pytest

from modules.lidar_logger.buffer import TwoSlotBuffer


def test_fifo_order_over_many_cycles() -> None:
    buf: TwoSlotBuffer[int] = TwoSlotBuffer()
    out = []
    for k in range(0, 20, 2):
        assert buf.put(k) and buf.put(k + 1)
        for _ in range(2):
            out.append(buf.take(0))
            buf.release()
    assert out == list(range(20)) and buf.dropped == 0


def test_a_third_scan_is_dropped_while_two_wait() -> None:
    buf: TwoSlotBuffer[str] = TwoSlotBuffer()
    assert buf.put("a") and buf.put("b")
    assert not buf.put("c")
    assert buf.dropped == 1 and buf.unwritten == 2
    assert buf.take(0) == "a"
    buf.release()
    assert buf.put("d")
    assert [buf.take(0), buf.release(), buf.take(0), buf.release()][::2] == ["b", "d"]


def test_the_slot_being_written_is_never_overwritten() -> None:
    buf: TwoSlotBuffer[list[int]] = TwoSlotBuffer()
    first = [1]
    buf.put(first)
    being_written = buf.take(0)
    assert buf.put([2])
    assert not buf.put([3]), "the only free-looking slot is the one being written"
    assert being_written is first and being_written == [1]
    buf.release()
    assert buf.take(0) == [2]


def test_take_times_out_when_empty_and_wakes_on_put() -> None:
    buf: TwoSlotBuffer[int] = TwoSlotBuffer()
    assert buf.take(0.01) is None
    threading.Timer(0.05, buf.put, args=(7,)).start()
    assert buf.take(5.0) == 7


def test_close_refuses_new_items_but_keeps_waiting_ones() -> None:
    buf: TwoSlotBuffer[int] = TwoSlotBuffer()
    buf.put(1)
    buf.close()
    assert not buf.put(2) and buf.refused_after_close == 1 and buf.dropped == 0
    assert buf.take(0) == 1


def test_release_without_take_is_a_bug() -> None:
    with pytest.raises(RuntimeError):
        TwoSlotBuffer().release()


def test_concurrent_producer_and_slow_writer_account_for_every_item() -> None:
    buf: TwoSlotBuffer[int] = TwoSlotBuffer()
    n = 5000
    accepted = []
    written = []

    def produce() -> None:
        for k in range(n):
            if buf.put(k):
                accepted.append(k)
        buf.close()

    t = threading.Thread(target=produce)
    t.start()
    while True:
        item = buf.take(0.01)
        if item is None:
            if not t.is_alive() and buf.unwritten == 0:
                break
            continue
        written.append(item)
        buf.release()
    t.join()
    assert written == accepted
    assert len(accepted) + buf.dropped == n
