"""Fixtures shared by every test: a real Zenoh router process, client sessions, child processes.

Everything runs on 127.0.0.1 with multicast scouting off, and everything started is stopped, also on failure.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from bbcs.testing import Processes, start_router

# helpers whose asserts check what tests see: rewritten so a failure shows the values, as in a test file
pytest.register_assert_rewrite("harness", "tests.system.uav_stack")


@pytest.fixture
def processes() -> Iterator[Processes]:
    procs = Processes()
    try:
        yield procs
    finally:
        procs.stop_all()


@pytest.fixture
def router(processes: Processes) -> int:
    """A real robot router (``cromat router``) on a free 127.0.0.1 port; yields the port."""
    return start_router(processes)


@pytest.fixture
def clients() -> Iterator[Callable[[int], object]]:
    """Factory of client sessions of the router on a given 127.0.0.1 port; all closed at teardown.

    Request it after the fixture that starts the router, so the sessions close before the router stops.
    """
    from bbcs.session import local_client, open_session

    opened = []

    def make(port: int):
        s = open_session(local_client(port))
        opened.append(s)
        return s

    try:
        yield make
    finally:
        for s in opened:
            s.close()


@pytest.fixture
def sessions(router: int, clients: Callable[[int], object]) -> Callable[[], object]:
    """Factory of client sessions of ``router``; all closed at teardown."""
    return lambda: clients(router)


HEAVY_STACKS = frozenset({
    "tests/system/test_fleet_mesh.py", "tests/system/test_fleet_alloc.py", "tests/system/test_fleet_mesh_loss.py",
    "tests/system/test_fleet_partition.py", "tests/system/test_fleet_scale.py", "tests/system/test_world_sync.py",
    "tests/system/test_survey_dtm.py", "tests/system/test_gcs_survey.py", "tests/modules/uquad/test_system_square.py",
})
"""Tests that run several robot stacks, or one with the lidar simulators' ray casting, for a minute or more.

Why one xdist group (``--dist loadgroup`` in pyproject.toml): two of them side by side put 30-40 processes on the
2 cores, and the DSP simulator then answers later than the seed's 4 x 0.25 s acknowledgement window. In one group
they run one after another on one worker while the other worker runs the rest of the suite."""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    root = config.rootpath
    for item in items:
        if item.path.relative_to(root).as_posix() in HEAVY_STACKS:
            item.add_marker(pytest.mark.xdist_group("heavy_stacks"))
