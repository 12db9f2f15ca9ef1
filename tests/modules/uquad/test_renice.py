"""The flight module's ``nice`` param renices every thread of its process (Linux niceness is per thread)."""

from __future__ import annotations

import subprocess
import sys

CHILD = """
import logging, os, threading
from modules.uquad.module import renice_process
before = threading.Thread(target=threading.Event().wait, args=(5,), daemon=True)
before.start()
renice_process(4, logging.getLogger())
after = threading.Thread(target=threading.Event().wait, args=(5,), daemon=True)
after.start()
print(sorted({os.getpriority(os.PRIO_PROCESS, int(t)) for t in os.listdir("/proc/self/task")}))
"""


def test_every_thread_before_and_after_gets_the_niceness() -> None:
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[4]", out.stdout + out.stderr
