"""World nodes on real Zenoh, shared by the world model's bus tests."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from ral.world_bus import WorldNode


@pytest.fixture
def nodes(router: int, clients) -> Iterator[Callable[..., WorldNode]]:  # noqa: ANN001
    """``nodes(robot, **kw)``: a WorldNode of ``robot`` on its own client session of the test's router (a fixed
    clock, a 0.2 s digest period); every node made is closed after the test, newest first."""
    made: list[WorldNode] = []

    def make(robot: str, **kw) -> WorldNode:  # noqa: ANN003
        node = WorldNode(clients(router), robot, lambda: 1000.0, digest_period_s=0.2, **kw)
        made.append(node)
        return node

    yield make
    for node in reversed(made):
        node.close()
