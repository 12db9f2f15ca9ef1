"""Shrinking a failing sequence (pure): the failure's cause is kept, everything else deleted, within the budget."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from campaign_shrink import shrink  # noqa: E402


def test_a_failure_needing_two_steps_shrinks_to_those_two_in_order() -> None:
    steps = list("abcdefghij")
    runs: list[list[str]] = []

    def fails(candidate: list[str]) -> bool:
        runs.append(candidate)
        return "c" in candidate and "h" in candidate and candidate.index("c") < candidate.index("h")

    out = shrink(steps, fails, budget=100)
    assert out.steps == ["c", "h"] and not out.exhausted
    assert out.runs == len(runs) and out.runs < 30


def test_one_step_alone_is_the_shortest_reproduction() -> None:
    out = shrink(list(range(9)), lambda c: 4 in c, budget=100)
    assert out.steps == [4]


def test_a_failure_that_needs_everything_stays_whole() -> None:
    steps = [1, 2, 3, 4]
    out = shrink(steps, lambda c: c == steps, budget=100)
    assert out.steps == steps and not out.exhausted


def test_the_budget_bounds_the_runs_and_says_so() -> None:
    out = shrink(list(range(40)), lambda c: 17 in c and 23 in c, budget=5)
    assert out.runs == 5 and out.exhausted
    assert 17 in out.steps and 23 in out.steps  # what is returned still fails


def test_a_flaky_failure_never_loses_its_cause() -> None:
    """A run that does not fail again (load, a race) keeps the steps it tried to delete."""
    answers = iter([False, True, False, False, True, False, False, False, False, False, False, False])
    out = shrink(list("abcdef"), lambda c: "d" in c and next(answers, False), budget=12)
    assert "d" in out.steps
