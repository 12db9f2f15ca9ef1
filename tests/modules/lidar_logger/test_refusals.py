"""Coalesced refusal reports: the first at once, then at most one a period with the count; nothing is lost."""

from __future__ import annotations

from modules.lidar_logger.refusals import Refusals


def test_first_refusal_reported_at_once_the_rest_coalesced_per_period() -> None:
    r = Refusals("LD-MRS", period_s=1.0)
    first = r.note(10.0, "scan cut short")
    assert first == "LD-MRS: scan cut short (1 refused so far)"
    assert [r.note(10.0 + 0.01 * k, "bad checksum") for k in range(1, 50)] == [None] * 49
    assert r.poll(10.9) is None
    later = r.poll(11.0)
    assert later is not None and "49 refused in the last 1.0 s (50 so far)" in later and "bad checksum" in later
    assert r.poll(12.5) is None  # nothing pending: nothing said
    assert r.note(12.5, "again") == "LD-MRS: again (51 refused so far)"
    assert r.total == 51 and r.reports == 3


def test_a_count_noted_at_once_is_one_report() -> None:
    r = Refusals("MTi-G")
    text = r.note(0.0, "frame dropped", count=7)
    assert text is not None and text.startswith("MTi-G: 7 refused") and r.total == 7
    assert r.note(0.1, "x", count=0) is None and r.total == 7
