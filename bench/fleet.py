"""Fleet task allocation (ral/allocation.py): cost against the central optimum, and time, for 2, 5 and 10 robots.

Random instances on a 1 km square (robots with random speed and battery). Two cases, each compared in the same
run against a centrally computed reference:

- one target per robot (n robots, n targets): the optimum is ``scipy.optimize.linear_sum_assignment`` over the
  same robot × target cost matrix the bids define; ratio = auction cost / optimum (≥ 1);
- 10–50 targets, routes of any length: the reference is a lower bound, the minimum spanning tree over the
  targets plus one node joined to every robot at cost 0 (each robot's route is a path from its start, so the
  routes plus those zero edges span that graph), in time units at the fastest robot's speed and full battery;
  the ratio to a bound overstates the true gap.

Measured in-process only (the algorithm, as every RAL would run it). ``realloc_s_10`` (time from a robot's death
on a real mesh to the survivors' new allocation) and ``clock_offset_p99_ms`` need the bus protocol between RALs,
which is not built: they are written as null with a note.

    python bench/fleet.py [--instances 40]

Writes bench/results/fleet.json with summary keys alloc_cost_ratio_10, alloc_time_p99_ms_10, realloc_s_10,
clock_offset_p99_ms.
"""

from __future__ import annotations

import argparse
import random
import statistics
import time

import benchlib  # noqa: F401  (puts the project on sys.path)
import numpy as np
from benchlib import pct, write_results
from scipy.optimize import linear_sum_assignment
from scipy.sparse.csgraph import minimum_spanning_tree

from ral.allocation import Bid, Target, allocate, cost_matrix, reallocate

ROBOTS = (2, 5, 10)
TARGETS = (10, 30, 50)


def instance(rng: random.Random, robots: int, targets: int) -> tuple[list[Target], list[Bid]]:
    ts = [Target(f"t{i:02d}", rng.uniform(0, 1000), rng.uniform(0, 1000)) for i in range(targets)]
    bs = [Bid(f"r{i:02d}", rng.uniform(0, 1000), rng.uniform(0, 1000), speed=rng.uniform(4, 8),
              battery=rng.uniform(0.3, 1.0)) for i in range(robots)]
    return ts, bs


def mst_bound(ts: list[Target], bs: list[Bid]) -> float:
    """Lower bound on the total weighted route time (see the module docstring)."""
    pts = np.array([[t.x, t.y] for t in ts])
    n = len(ts)
    d = np.zeros((n + 1, n + 1))
    d[:n, :n] = np.hypot(pts[:, None, 0] - pts[None, :, 0], pts[:, None, 1] - pts[None, :, 1])
    starts = np.array([[b.x, b.y] for b in bs])
    to_robot = np.hypot(pts[:, None, 0] - starts[None, :, 0], pts[:, None, 1] - starts[None, :, 1]).min(axis=1)
    d[:n, n] = d[n, :n] = np.maximum(to_robot, 1e-9)  # node n: every robot start merged (distance to the nearest)
    vmax = max(b.speed for b in bs)
    return float(minimum_spanning_tree(d).sum()) / vmax


def timed(fn):  # type: ignore[no-untyped-def]
    t = time.perf_counter()
    out = fn()
    return out, (time.perf_counter() - t) * 1000


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--instances", type=int, default=40, help="random instances per case (default 40)")
    ap.add_argument("--seed", type=int, default=17)
    ap.add_argument("--out", help="results file (default bench/results/fleet.json)")
    args = ap.parse_args()
    rng = random.Random(args.seed)
    rows = []
    summary: dict[str, object] = {}
    print(f"{'robots':>6} {'targets':>7} {'reference':>10} {'ratio mean':>10} {'ratio max':>9} "
          f"{'alloc p50 ms':>12} {'alloc p99 ms':>12} {'ref p50 ms':>10} {'realloc p99 ms':>14}")
    for n in ROBOTS:
        cases = [(n, "optimum (LSA)")] + [(t, "MST bound") for t in TARGETS]
        for targets, ref_name in cases:
            ratios, times, ref_times, re_times = [], [], [], []
            for _ in range(args.instances if targets <= 30 else max(5, args.instances // 4)):
                ts, bs = instance(rng, n, targets)
                one = ref_name.startswith("optimum")
                alloc, ms = timed(lambda ts=ts, bs=bs, one=one: allocate(ts, bs, max_per_robot=1 if one else None))
                if one:
                    def opt(ts=ts, bs=bs) -> float:
                        m = np.array(cost_matrix(ts, bs))
                        r, c = linear_sum_assignment(m)
                        return float(m[r, c].sum())
                    ref, ref_ms = timed(opt)
                else:
                    ref, ref_ms = timed(lambda ts=ts, bs=bs: mst_bound(ts, bs))
                ratios.append(alloc.cost / ref)
                times.append(ms)
                ref_times.append(ref_ms)
                gone = max(alloc.routes, key=lambda r, a=alloc: len(a.routes[r]))
                if n > 1:
                    _, rms = timed(lambda a=alloc, ts=ts, bs=bs, g=gone, one=one: reallocate(
                        a, ts, [b for b in bs if b.robot != g], now=0.0, max_per_robot=None))
                    re_times.append(rms)
            row = {"robots": n, "targets": targets, "reference": ref_name, "instances": len(ratios),
                   "ratio_mean": statistics.fmean(ratios), "ratio_max": max(ratios),
                   "alloc_p50_ms": pct(times, 50), "alloc_p99_ms": pct(times, 99),
                   "reference_p50_ms": pct(ref_times, 50), "realloc_compute_p99_ms": pct(re_times, 99)}
            rows.append(row)
            print(f"{n:>6} {targets:>7} {ref_name:>10.10} {row['ratio_mean']:>10.3f} {row['ratio_max']:>9.3f} "
                  f"{row['alloc_p50_ms']:>12.2f} {row['alloc_p99_ms']:>12.2f} {row['reference_p50_ms']:>10.2f} "
                  f"{row['realloc_compute_p99_ms']:>14.2f}")
            if n == 10 and targets == 10:
                summary["alloc_cost_ratio_10"] = round(row["ratio_mean"], 4)
                summary["alloc_cost_ratio_max_10"] = round(row["ratio_max"], 4)
                summary["alloc_time_p99_ms_10"] = round(row["alloc_p99_ms"], 3)
    summary["realloc_s_10"] = None
    summary["clock_offset_p99_ms"] = None
    notes = {
        "alloc_cost_ratio_10": "mean over random instances of auction cost / linear_sum_assignment optimum, 10 robots "
                               "x 10 targets, one target per robot, same cost matrix",
        "alloc_time_p99_ms_10": "p99 of one in-process allocation, 10 robots x 10 targets (one per robot)",
        "realloc_s_10": "not measured: the bid protocol between RALs over the mesh is not built; only the "
                        "in-process re-allocation compute time is in the rows (realloc_compute_p99_ms)",
        "clock_offset_p99_ms": "not measured: no time synchronisation between robots is built yet",
    }
    write_results("fleet", {"summary": summary, "notes": notes, "rows": rows,
                            "instances": args.instances, "seed": args.seed}, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
