"""Route drift: the manager's view of a module's routes must be the routes the module really reads.

A module says which slot each routed input reads in every RouteAck (``@route``). When that differs from what
the manager believes it set (a CONTROL_ENTRADA that did not come from the manager, a lost update, a restart with
stale routes), the manager's view is wrong and a route swap to the value it believes in would "succeed" and
change nothing (issue 12, item 3). ``route_drift`` finds the differences; the manager reports them and repairs
the module by publishing its CONTROL_ENTRADA again.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RouteDrift:
    """One routed input whose real slot number differs from the manager's (None: the module did not report it)."""

    module: str
    input: str
    expected: int
    actual: int | None

    def __str__(self) -> str:
        actual = "nothing" if self.actual is None else self.actual
        return f"{self.module}.{self.input} reads {actual}, the manager set {self.expected}"


def route_drift(module: str, expected: dict[str, int], reported: dict[str, int]) -> list[RouteDrift]:
    """The inputs of ``module`` whose reported route is not the expected one, in the expected inputs' order."""
    return [RouteDrift(module, name, number, reported.get(name))
            for name, number in expected.items() if reported.get(name) != number]


def describe(drifts: list[RouteDrift]) -> str:
    """One line for the log and the manager's report."""
    return "route drift, repairing: " + "; ".join(str(d) for d in drifts)
