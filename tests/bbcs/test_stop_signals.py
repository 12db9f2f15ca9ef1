"""``bbcs.stop_signals``: stop signals reach a callback that takes locks, even while the main thread holds them,
and a burst of signals does not nest; after ``restore`` a stop signal has its default effect again. In a child
process: signals are sent to it, not to pytest."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

from bbcs.testing import child_env

CHILD = textwrap.dedent("""
    import sys, threading
    from bbcs.stop_signals import forward_stop_signals
    lock = threading.Lock()
    got = []

    def on_stop(signum):
        with lock:  # the main thread holds this lock nearly all the time
            got.append(signum)

    restore = forward_stop_signals(on_stop)
    print("ready", flush=True)
    while not got:
        with lock:
            for _ in range(2000):
                pass
    restore()
    print("stopped", got[0], flush=True)
    sys.stdin.read()  # restored: the next SIGTERM ends the process (default action)
""")


def test_a_burst_of_stop_signals_reaches_a_callback_that_takes_the_main_threads_lock() -> None:
    proc = subprocess.Popen([sys.executable, "-c", CHILD], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, env=child_env())
    try:
        assert proc.stdout.readline().strip() == "ready"
        for _ in range(20):
            proc.send_signal(signal.SIGTERM)
        assert proc.stdout.readline().strip() == f"stopped {int(signal.SIGTERM)}"
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == -signal.SIGTERM
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
