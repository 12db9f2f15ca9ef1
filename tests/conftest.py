"""Fixtures shared by every test: a real Zenoh router process, client sessions, child processes.

Everything runs on 127.0.0.1 with multicast scouting off, and everything started is stopped, also on failure.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path

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
    "tests/system/test_fleet_mesh.py", "tests/system/test_fleet_mesh_loss.py",
    "tests/system/test_fleet_partition.py", "tests/system/test_fleet_scale.py", "tests/system/test_world_sync.py",
    "tests/system/test_fleet_secure_launch.py", "tests/system/test_fleet_mixed.py",
    "tests/cromat/mavlink/test_uquad_fleet.py",
})
"""Test files that run several free-running robot stacks (fleets not in lockstep: partitions, mesh loss, the mixed
and secured fleets, which a fleet in lockstep cannot or does not yet fly; docs/simulation.md).

Two of them side by side put 30-40 processes on the 2 cores, and simulators then answer later than the seed's
acknowledgement windows. A robot in lockstep does not: its simulators wait for its modules, so a loaded machine
slows its flight and changes nothing in it (docs/simulation.md); the lidar survey, the uQuad's flights and the
survey tests left this unit when they moved onto lockstep, as did the fleet allocation and robot-death tests when they
moved onto a fleet in lockstep (``[sim] fleet``, ``[fleet] lockstep``). Under xdist they form one work unit
(``pytest_xdist_make_scheduler`` below): one worker runs them one after another, from the start of the run, while
the other workers run the rest of the suite."""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Heavy files first (a stable sort: their own order kept), so their one work unit starts at once; within
    them, the files with an ``alone`` test first. At the start of the run the other workers are in the
    unit-test files xdist hands out first (the ones with most tests), and the ``alone`` file waits seconds for
    them to end; placed last, it would wait for whatever long system file was running."""
    root = config.rootpath
    alone = config.stash[_alone_files] = {item.path for item in items if item.get_closest_marker("alone") is not None}
    items.sort(key=lambda item: (item.path.relative_to(root).as_posix() not in HEAVY_STACKS, item.path not in alone))


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


# ------------------------------------------------------------------ test files that run alone under xdist
#
# A test marked ``alone`` (ten robot stacks: about 80 processes) takes both cores for a minute; beside it, the other
# workers' tests missed their deadlines. Pausing the other workers between two tests is not enough: a module-scoped
# robot stack of a file it is half-way through keeps running, slows the ten robots and is starved by them (a CI run
# with per-test turns lost a pan command of such a stack). So each xdist worker holds a turn per test *file*, from
# its first test's set-up to its last test's tear-down (its module fixtures with it): shared for ordinary files,
# exclusive for a file with an ``alone`` test, which therefore starts once the other workers have finished their
# current files, and no new file starts meanwhile (bbcs.testing.run_turn). Without xdist, nothing is locked.

ALONE_DIR = "cromat_alone_dir"
_alone_dir = pytest.StashKey[str]()
_alone_files = pytest.StashKey[set[Path]]()


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "alone: under xdist, its file runs while no other worker runs a test file")
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


class _FileTurn:
    """This worker's turn for the test file it is running (one at a time: xdist runs a worker's items in order)."""

    path: Path | None = None
    held = ExitStack()


@pytest.hookimpl(hookwrapper=True, tryfirst=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    """Outermost (``tryfirst``): the wait for a turn is not counted in pytest-timeout's limit."""
    folder = getattr(item.config, "workerinput", {}).get(ALONE_DIR)
    if folder is None:
        yield
        return
    if _FileTurn.path != item.path:
        _FileTurn.held.close()
        _FileTurn.held.enter_context(run_turn(folder, item.path in item.config.stash[_alone_files]))
        _FileTurn.path = item.path
    try:
        yield
    finally:
        if nextitem is None or nextitem.path != item.path:  # its module fixtures were torn down with this item
            _FileTurn.held.close()
            _FileTurn.path = None
