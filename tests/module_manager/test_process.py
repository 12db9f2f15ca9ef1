"""``module_manager.process.Child``: a child placed on processors (``cpus``) runs there from its first instruction;
one whose processors are not there any more (a cpuset changed after the manifest was checked) does not run at all,
exits ``CPUS_REFUSED`` and says why in its log."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from module_manager.process import CPUS_REFUSED, Child

PROBE = "import os; print(sorted(os.sched_getaffinity(0)), flush=True)"


def test_a_child_runs_on_the_processors_given(tmp_path):
    cpu = max(os.sched_getaffinity(0))
    child = Child("probe", [sys.executable, "-c", PROBE], dict(os.environ), log_dir=tmp_path, cpus=frozenset({cpu}))
    try:
        assert child.proc.wait(30) == 0
    finally:
        child.close()
    assert (tmp_path / "probe.log").read_text().strip() == f"[{cpu}]"


def test_a_child_that_cannot_be_placed_does_not_run_and_says_why(tmp_path):
    marker = tmp_path / "ran"
    child = Child("probe", [sys.executable, "-c", f"open({str(marker)!r}, 'w')"], dict(os.environ),
                  log_dir=tmp_path, cpus=frozenset({4096}))
    try:
        assert child.proc.wait(30) == CPUS_REFUSED
    finally:
        child.close()
    assert not marker.exists(), "the program never started"
    log = Path(tmp_path / "probe.log").read_text()
    assert log.startswith("cannot run on cpus [4096]: [Errno 22]"), log
