"""What every benchmark shares: the project on ``sys.path``, one percentile, stopping a launched process group, a
working folder, and writing ``bench/results/NAME.json``.

Benchmarks run as ``python bench/NAME.py`` from a checkout, so this file sits beside them and is imported first.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
# A bench runs as ``python bench/NAME.py``, so bench/ is sys.path[0]: the project's packages must come before it,
# or a bench's file shadows a package of the same name (bench/control.py hid ``control``, which the DSP and uQuad
# simulators import, and every bench using them failed). Imported before any project package, by every bench.
if str(ROOT) in sys.path:
    sys.path.remove(str(ROOT))
sys.path.insert(0, str(ROOT))
RESULTS = ROOT / "bench" / "results"


@contextmanager
def work_dir(prefix: str) -> Iterator[Path]:
    """A fresh folder for a run's manifests, records and logs: removed when the run ends well, kept (and named on
    stderr) when it fails, so its logs can be read. Nothing is left in /tmp by a run that worked."""
    work = Path(tempfile.mkdtemp(prefix=prefix))
    try:
        yield work
    except BaseException:
        print(f"the run's manifests, records and logs are kept in {work}", file=sys.stderr)
        raise
    shutil.rmtree(work, ignore_errors=True)


def pct(values: list[float], q: float, *, empty: float | None = None) -> float:
    """The ``q``-th percentile (0–100) of ``values``: the sample at that rank, no interpolation. The one percentile
    of the benchmarks. No values: ``empty`` if given (e.g. NaN for a run that failed early), else ValueError."""
    if not values:
        if empty is None:
            raise ValueError("a percentile of no values")
        return empty
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q / 100 * (len(ordered) - 1))))]


def write_results(name: str, result: dict[str, Any], out: str | Path | None = None) -> Path:
    """Write ``result`` (which holds the issue's ``summary`` object) as JSON, by default to results/NAME.json."""
    if "summary" not in result:
        raise ValueError(f"benchmark {name!r}: its result has no 'summary' object")
    path = Path(out) if out is not None else RESULTS / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}")
    return path


def stop_group(proc: subprocess.Popen, grace_s: float = 30.0) -> None:
    """SIGTERM to a launch (``start_new_session``), then SIGKILL to its whole process group after ``grace_s``."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
