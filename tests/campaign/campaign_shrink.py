"""Shrinking a failing sequence to a short reproduction: delete what the failure does not need (pure).

Each try runs a candidate sequence on the robot again (``fails`` answers whether the same breach kind came back),
which costs simulated flight, so the search is greedy and bounded: chunks of half the sequence, then quarters,
down to single steps, each deletion kept when the failure stays, at most ``budget`` runs.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

T = TypeVar("T")


@dataclass
class Shrunk:
    steps: list
    runs: int
    """How many candidate sequences were run."""
    exhausted: bool
    """True when the budget ran out before single steps were tried: a shorter reproduction may exist."""


def shrink(steps: Sequence[T], fails: Callable[[list[T]], bool], budget: int = 20) -> Shrunk:
    """The shortest sub-sequence of ``steps`` (order kept) found that still ``fails``, deleting chunks greedily.
    ``steps`` itself is taken to fail (it is not run again)."""
    current = list(steps)
    runs = 0
    chunk = max(1, len(current) // 2)
    while True:
        i = 0
        removed = False
        while i < len(current):
            candidate = current[:i] + current[i + chunk:]
            if not candidate:
                i += chunk
                continue
            if runs >= budget:
                return Shrunk(current, runs, exhausted=True)
            runs += 1
            if fails(candidate):
                current = candidate
                removed = True
            else:
                i += chunk
        if chunk == 1 and not removed:
            return Shrunk(current, runs, exhausted=False)
        chunk = max(1, chunk // 2)
