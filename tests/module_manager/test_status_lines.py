"""Status lines come out whole when several threads print them at once (``module_manager/status_lines.py``).

A fleet launcher reads each robot's "all N modules up" line and a test reads the launcher's "fleet: all 10 robots
up" line by their start. With ``print()`` from eight threads, 551 of 24,000 lines came out glued to another one
(measured on this machine), and a reader waiting for one of them waited until its deadline.
"""

from __future__ import annotations

import re
import subprocess
import sys

from bbcs.testing import child_env

CHILD = """
import threading
from module_manager.status_lines import print_line

def run(k):
    for i in range(3000):
        print_line(f"[t{k}] line {i} " + "x" * 40)

threads = [threading.Thread(target=run, args=(k,)) for k in range(8)]
for t in threads:
    t.start()
for t in threads:
    t.join()
"""


def test_lines_printed_by_eight_threads_at_once_come_out_whole_and_all() -> None:
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, env=child_env(), timeout=60,
                         check=True).stdout
    lines = out.splitlines()
    whole = re.compile(r"\[t([0-7])\] line (\d+) x{40}")
    broken = [x for x in lines if not whole.fullmatch(x)]
    assert not broken, f"{len(broken)} lines glued or cut, e.g. {broken[:3]}"
    assert sorted((int(m[1]), int(m[2])) for m in map(whole.fullmatch, lines)) == [
        (k, i) for k in range(8) for i in range(3000)], "every line once"


def test_a_closed_reader_does_not_stop_the_printer() -> None:
    """Whoever read our stdout has gone: the next lines are dropped quietly and the program goes on to its end."""
    child = CHILD.replace("range(3000)", "range(20000)") + "\nimport sys\nsys.stderr.write('finished\\n')\n"
    proc = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=child_env(), text=True)
    assert proc.stdout is not None
    first = proc.stdout.readline()
    proc.stdout.close()
    _, err = proc.communicate(timeout=60)
    assert first.startswith("[t")
    assert proc.returncode == 0 and "finished" in err, err
