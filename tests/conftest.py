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

