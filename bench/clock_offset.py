"""The fleet bench's clock-offset figure (``clock_offset_p99_ms``): robots with known skewed, drifting clocks, each
behind its own router (routers chained as a fleet's are), run the RAL's clock service and tracker
(ral/sync_bus.py) on real Zenoh; every estimate is compared with the true offset at that instant.

Bench code, not runtime code: it starts routers (bbcs.testing.Processes), so it lives here and not in ``ral``.
bench/fleet.py reports it; ``python bench/clock_offset.py [--smoke] [--out FILE]`` measures it alone.
"""

from __future__ import annotations

import argparse
import json
import random
import subprocess
import threading
import time

import benchlib  # noqa: F401  (puts the project on sys.path)
import zenoh
from benchlib import pct, write_results

from bbcs import local_client, open_session
from bbcs.net import free_port, wait_tcp
from bbcs.testing import Processes
from ral import sync
from ral.sync_bus import ClockService, ClockTracker


def measure_offsets_on_bus(*, n_robots: int, duration_s: float, skew_s: float, drift_ppm: float,
                           seed: int) -> list[float]:
    """Estimate − truth (seconds) of every offset estimate made while ``n_robots`` skewed clocks, each behind its
    own router (routers chained through Zenoh's routing), probe one another for ``duration_s``."""
    rng = random.Random(seed)
    clocks = {f"r{i}": sync.SkewedClock(offset_s=rng.uniform(-skew_s, skew_s),
                                        drift_ppm=rng.uniform(-drift_ppm, drift_ppm)) for i in range(n_robots)}
    procs = Processes()
    sessions: list[zenoh.Session] = []
    services: list[ClockService] = []
    trackers: list[ClockTracker] = []
    errors: list[float] = []
    lock = threading.Lock()
    try:
        ports: list[int] = []
        for _ in range(n_robots):
            port = free_port()
            extra = ["--connect", f"tcp/127.0.0.1:{ports[-1]}"] if ports else []
            procs.start(["-m", "bbcs.router", "--listen", f"tcp/127.0.0.1:{port}", *extra],
                        stdout=subprocess.DEVNULL)
            wait_tcp("127.0.0.1", port, 10.0)
            ports.append(port)
        names = sorted(clocks)
        for name, port in zip(names, ports, strict=True):
            session = open_session(local_client(port))
            sessions.append(session)
            services.append(ClockService(session, name, clocks[name]))
        for name, session in zip(names, sessions, strict=True):

            def on_sample(peer: str, sample: sync.ClockSample, est: sync.Estimate, own: str = name) -> None:
                base = time.time()
                truth = clocks[peer].error_at(base) - clocks[own].error_at(base)
                with lock:
                    errors.append(est.offset_s - truth)

            trackers.append(ClockTracker(session, name, clocks[name], peers=[p for p in names if p != name],
                                         period_s=0.2, publish=False, on_sample=on_sample))
        time.sleep(duration_s)
    finally:
        for tracker in trackers:
            tracker.close()
        for service in services:
            service.close()
        for session in sessions:
            session.close()
        procs.stop_all()
    return errors


def measure_clock_offset_p99_ms(n_robots: int = 5, duration_s: float = 6.0, skew_s: float = 2.0,
                                drift_ppm: float = 50.0, seed: int = 17) -> dict[str, float]:
    """p50/p99/max of |estimate − truth| in ms over ``n_robots`` clocks skewed by up to ±``skew_s`` and drifting
    up to ±``drift_ppm``, every robot probing every other for ``duration_s``; and the sample count."""
    errors = measure_offsets_on_bus(n_robots=n_robots, duration_s=duration_s, skew_s=skew_s,
                                    drift_ppm=drift_ppm, seed=seed)
    ms = [abs(e) * 1000.0 for e in errors]
    if not ms:
        raise RuntimeError("no clock offset estimate was made on the bus")
    return {"clock_offset_p99_ms": pct(ms, 99), "clock_offset_p50_ms": pct(ms, 50), "clock_offset_max_ms": max(ms),
            "clock_offset_samples": float(len(ms)), "clock_robots": float(n_robots)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="2 robots for 1 s")
    ap.add_argument("--out", help="result file (default bench/results/clock_offset.json)")
    args = ap.parse_args()
    got = measure_clock_offset_p99_ms(n_robots=2, duration_s=1.0) if args.smoke else measure_clock_offset_p99_ms()
    print(json.dumps(got, indent=2))
    write_results("clock_offset", {"summary": got, "smoke": args.smoke}, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
