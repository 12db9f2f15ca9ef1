"""Helpers shared by the DSP tests."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
UAV1 = ROOT / "bbcs_conf" / "uav1.conf"


def wait_for(predicate: Callable[[], bool], what: str, deadline_s: float = 10.0) -> None:
    """Poll until ``predicate`` holds; fail naming ``what`` at the deadline (no fixed sleeps)."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if predicate():
            return
        time.sleep(0.005)
    raise AssertionError(f"timed out after {deadline_s} s waiting for {what}")
