"""Fixtures shared by every test: a real Zenoh router process, client sessions, child processes.

Everything runs on 127.0.0.1 with multicast scouting off, and everything started is stopped, also on failure.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable, Iterator

import pytest

from bbcs.testing import Processes, run_turn, start_router

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
    "tests/system/test_fleet_secure_launch.py", "tests/system/test_fleet_mixed.py",
})
"""Test files that run several robot stacks, or one with the lidar simulators' ray casting, for a minute or more.

Two of them side by side put 30-40 processes on the 2 cores, and simulators then answer later than the seed's
acknowledgement windows. Under xdist they form one work unit (``pytest_xdist_make_scheduler`` below): one worker
runs them one after another, from the start of the run, while the other worker runs the rest of the suite."""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Heavy files first (a stable sort: their own order kept), so their one work unit starts at once; within
    them, the tests marked ``alone`` last (by then the other worker has most often finished its share)."""
    root = config.rootpath
    items.sort(key=lambda item: (item.path.relative_to(root).as_posix() not in HEAVY_STACKS,
                                 item.get_closest_marker("alone") is not None))


# ------------------------------------------------------------------ tests that run alone under xdist
#
# A test marked ``alone`` (ten robot stacks: about 70 processes) takes both cores for a minute; beside it, the other
# worker's tests miss their deadlines. Each xdist worker runs every test's whole protocol (its module fixtures'
# set-up and tear-down included) holding a shared lock on one file, an ``alone`` test an exclusive one: the other
# worker waits between two of its tests, its module-scoped stacks idle, until the ``alone`` test is done
# (bbcs.testing.run_turn). Without xdist, nothing is locked.

ALONE_DIR = "cromat_alone_dir"
_alone_dir = pytest.StashKey[str]()


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "alone: under xdist, run while no other worker runs a test")
    if not hasattr(config, "workerinput"):  # the controller (or a run without xdist)
        config.stash[_alone_dir] = tempfile.mkdtemp(prefix="cromat-alone-")


def pytest_unconfigure(config: pytest.Config) -> None:
    folder = config.stash.get(_alone_dir, None)
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node: object) -> None:
    """xdist, on the controller: each worker learns the run's lock folder."""
    node.workerinput[ALONE_DIR] = node.config.stash[_alone_dir]  # type: ignore[attr-defined]


@pytest.hookimpl(hookwrapper=True, tryfirst=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    """Outermost (``tryfirst``): the wait for a turn is not counted in pytest-timeout's limit."""
    folder = getattr(item.config, "workerinput", {}).get(ALONE_DIR)
    if folder is None:
        yield
        return
    with run_turn(folder, item.get_closest_marker("alone") is not None):
        yield


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object | None:
    """For the configured ``--dist loadfile`` (pyproject.toml): work units of whole files (a module-scoped robot
    stack starts once, on one worker, and tests numbered to run in order on it do), all ``HEAVY_STACKS`` files one
    unit. Another ``--dist`` given on the command line is left to xdist."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class HeavyTogetherScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            path = nodeid.split("::", 1)[0]
            return "heavy_stacks" if path in HEAVY_STACKS else path

    return HeavyTogetherScheduling(config, log)
