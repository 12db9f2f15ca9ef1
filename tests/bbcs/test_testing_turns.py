"""``bbcs.testing.run_turn``: how pytest-xdist workers keep an ``alone`` test (ten robot stacks) from running beside
any other test. Threads stand for workers: each ``run_turn`` opens its own files, so their flocks conflict as
separate processes' do."""

from __future__ import annotations

import threading
from pathlib import Path

from bbcs.testing import run_turn


class Turn(threading.Thread):
    """Takes a turn, says so, and holds it until released."""

    def __init__(self, folder: Path, alone: bool) -> None:
        super().__init__(daemon=True)
        self.folder, self.alone = folder, alone
        self.started_turn, self.release = threading.Event(), threading.Event()

    def run(self) -> None:
        with run_turn(self.folder, self.alone):
            self.started_turn.set()
            self.release.wait(10)


def test_shared_turns_run_side_by_side(tmp_path: Path) -> None:
    a, b = Turn(tmp_path, False), Turn(tmp_path, False)
    a.start()
    assert a.started_turn.wait(5)
    b.start()
    assert b.started_turn.wait(5)
    a.release.set(), b.release.set()
    a.join(5), b.join(5)


def test_an_alone_turn_waits_for_the_running_test_and_holds_back_the_next(tmp_path: Path) -> None:
    running = Turn(tmp_path, False)
    running.start()
    assert running.started_turn.wait(5)
    alone = Turn(tmp_path, True)
    alone.start()
    assert not alone.started_turn.wait(0.3), "the alone test started beside a running test"
    later = Turn(tmp_path, False)
    later.start()
    running.release.set()
    assert alone.started_turn.wait(5), "the alone test never started once the running test ended"
    assert not later.started_turn.wait(0.3), "a test started beside the alone test"
    alone.release.set()
    assert later.started_turn.wait(5), "the next test never started once the alone test ended"
    later.release.set()
    for t in (running, alone, later):
        t.join(5)
        assert not t.is_alive()
