"""Every benchmark still runs: ``python bench/NAME.py --smoke --out FILE`` (its smallest settings, seconds) ends
with exit 0 and writes its result with a ``summary``, so a benchmark broken by a change elsewhere fails CI.

A bench is found by its file (every ``bench/*.py`` but the shared helpers): a new one without ``--smoke`` fails
here until it has one. The runs start together, ``PARALLEL`` at a time (most of a run is waiting on child
processes), when the first test of this file asks for its result; each test waits for its own.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import pytest

from bbcs.testing import child_env

ROOT = Path(__file__).resolve().parents[2]
BENCH = ROOT / "bench"
HELPERS = {"benchlib", "bus_peers"}
"""Files in bench/ that are imported by the benchmarks, not run."""
EXTRA: dict[str, list[str]] = {}
"""Arguments beside ``--smoke``, by bench (none yet: ``bus.py --secure`` would double the bus run)."""
PARALLEL = 2
"""Two at a time, one per core: a third robot launching beside two others left routers not listening within their
30 s at a load of 50."""
RUN_TIMEOUT_S = 110.0
STOP_GRACE_S = 20.0
pytestmark = pytest.mark.timeout(RUN_TIMEOUT_S + 40)  # a test waits for its own run, which may start late


def benches() -> list[str]:
    return sorted(p.stem for p in BENCH.glob("*.py") if p.stem not in HELPERS)


def cyclonedds_missing() -> str | None:
    try:
        import cyclonedds  # noqa: F401
    except Exception as exc:
        return f"bench/bus.py --peers compares with Cyclone DDS, an optional extra not installed here ({exc}); " \
               "pip install '.[bench]' to run it"
    return None


class Runs:
    """The smoke runs, started on a pool; every child process group stopped at the end."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.pool = ThreadPoolExecutor(PARALLEL, thread_name_prefix="bench-smoke")
        self.lock = threading.Lock()
        self.running: set[int] = set()
        self.stopping = False
        self.futures: dict[str, Future[tuple[int, str, Path]]] = {}

    def start(self, cases: list[tuple[str, list[str]]]) -> None:
        for key, args in cases:
            self.futures[key] = self.pool.submit(self._run, key, args)

    def _run(self, key: str, args: list[str]) -> tuple[int, str, Path]:
        out = self.folder / f"{key}.json"
        name = key.split(":")[0]
        cmd = [sys.executable, str(BENCH / f"{name}.py"), "--smoke", "--out", str(out), *args]
        with self.lock:
            if self.stopping:
                return -1, "not run: the tests stopped", out
            proc = subprocess.Popen(cmd, cwd=str(ROOT), env=child_env(), stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True, start_new_session=True)
            self.running.add(proc.pid)
        try:
            text, _ = proc.communicate(timeout=RUN_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            text = self._interrupt(proc) + f"\n[stopped after {RUN_TIMEOUT_S:g} s]"
        finally:
            with self.lock:
                self.running.discard(proc.pid)
            self._kill(proc.pid)  # whatever the bench left running in its process group
        return proc.returncode, text, out

    def _interrupt(self, proc: subprocess.Popen) -> str:
        """Ctrl+C first, so the bench's ``finally`` stops what it launched in sessions of its own (a robot's
        manager); its process group killed only after a grace."""
        try:
            proc.send_signal(signal.SIGINT)
            text, _ = proc.communicate(timeout=STOP_GRACE_S)
        except subprocess.TimeoutExpired:
            self._kill(proc.pid)
            text, _ = proc.communicate()
        return text

    @staticmethod
    def _kill(pgid: int) -> None:
        try:
            os.killpg(pgid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass

    def close(self) -> None:
        with self.lock:
            self.stopping = True
            running = list(self.running)
        for pid in running:  # the tests stopped early: their runs get Ctrl+C, then the grace, then SIGKILL
            try:
                os.kill(pid, signal.SIGINT)
            except ProcessLookupError:
                pass
        self.pool.shutdown(wait=False, cancel_futures=True)
        for future in self.futures.values():
            try:
                future.result(timeout=STOP_GRACE_S + 5)
            except Exception:
                pass
        for pid in running:
            self._kill(pid)


def cases() -> list[tuple[str, list[str]]]:
    out = [(name, EXTRA.get(name, [])) for name in benches()]
    if cyclonedds_missing() is None:
        out.append(("bus:peers", ["--peers"]))
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Runs]:
    r = Runs(tmp_path_factory.mktemp("bench_smoke"))
    try:
        r.start(cases())
        yield r
    finally:
        r.close()


def check(runs: Runs, key: str) -> None:
    code, text, out = runs.futures[key].result(timeout=RUN_TIMEOUT_S + STOP_GRACE_S + 10)
    tail = "\n".join(text.splitlines()[-30:])
    assert code == 0, f"bench/{key} --smoke exited {code}:\n{tail}"
    assert out.exists(), f"bench/{key} --smoke wrote no result file:\n{tail}"
    result = json.loads(out.read_text())
    assert isinstance(result.get("summary"), dict) and result["summary"], f"bench/{key}: no summary in {out}"


@pytest.mark.parametrize("name", benches())
def test_benchmark_still_runs(runs: Runs, name: str) -> None:
    check(runs, name)


def test_bus_peers_still_runs(runs: Runs) -> None:
    why = cyclonedds_missing()
    if why is not None:
        pytest.skip(why)
    check(runs, "bus:peers")
