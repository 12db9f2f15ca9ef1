"""Fleet task allocation (ral/allocation.py): cost against the central optimum, and time, for 2, 5 and 10 robots.

Random instances on a 1 km square (robots with random speed and battery). Two cases, each compared in the same
run against a centrally computed reference:

- one target per robot (n robots, n targets): the optimum is ``scipy.optimize.linear_sum_assignment`` over the
  same robot × target cost matrix the bids define; ratio = auction cost / optimum (≥ 1);
- 10–50 targets, routes of any length: the reference is a lower bound, the minimum spanning tree over the
  targets plus one node joined to every robot at cost 0 (each robot's route is a path from its start, so the
  routes plus those zero edges span that graph), in time units at the fastest robot's speed and full battery;
  the ratio to a bound overstates the true gap.

The algorithm is timed in-process (as every RAL runs it). Then over the bus (``--bus-trials``, default 3):
10 agent processes, each the RAL's real fleet code (``ral/fleet.py``'s FleetLink and the protocol) with its own
Zenoh router, the routers meshed (star on the first), each agent flying a simulated point robot (no DSP stack:
the protocol is what is measured). A ground station posts 30 targets; the time until all 10 agents agree is
``alloc_bus_ms``; then the agent holding most targets is SIGKILLed with its router, and ``realloc_s_10`` is the
time from the kill to the moment the last survivor decided the new round (every survivor with the same digest);
the worst trial is reported. ``clock_offset_p99_ms`` is the error of the RAL's clock-offset estimator
(ral/sync.py). ``--scale S`` also launches bbcs_conf/fleet10_sim.toml and measures CPU per robot and
the payload bytes per robot a ground station on the hub receives, over S seconds.

    python bench/fleet.py [--instances 40] [--bus-trials 3]

Writes bench/results/fleet.json with summary keys alloc_cost_ratio_10, alloc_time_p99_ms_10, realloc_s_10,
clock_offset_p99_ms.
"""

from __future__ import annotations

import argparse
import math
import os
import random
import signal
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import benchlib  # noqa: F401  (puts the project on sys.path)
import numpy as np
from benchlib import pct, write_results
from scipy.optimize import linear_sum_assignment
from scipy.sparse.csgraph import minimum_spanning_tree

from bbcs import keys, local_client, open_session
from bbcs.contracts.fleet import FleetTarget, FleetTask
from bbcs.net import free_port, wait_tcp
from bbcs.testing import child_env, stop_process, wait_port
from ral.allocation import Bid, Target, allocate, cost_matrix, reallocate
from ral.fleet import FleetLink
from ral.fleet_gcs import FleetView
from ral.fleet_protocol import Execute, FleetConfig, OwnState, horizontal_m

LAT0, LON0, ALT = 37.4117, -6.0025, 22.0
M_LAT = 1 / 111_320
BUS_ROBOTS = 10
BUS_TARGETS = 30

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


def agent(name: str, port: int, north_m: float, east_m: float, speed: float) -> int:
    """One robot's fleet side: the RAL's FleetLink on its own router, flying a point robot toward its share."""
    if not wait_tcp("127.0.0.1", port, 30):
        print(f"no router on 127.0.0.1:{port}", flush=True)
        return 1
    session = open_session(local_client(port))
    token = session.liveliness().declare_token(keys.alive_key(name, "ral"))
    pos = [LAT0 + north_m * M_LAT, LON0 + east_m * M_LAT / math.cos(math.radians(LAT0))]
    route: list[FleetTarget] = []
    lock = threading.Lock()

    def own() -> OwnState:
        with lock:
            return OwnState(lat=pos[0], lon=pos[1], alt=ALT, speed=speed, can_do=frozenset({"visit"}),
                            flying_share=True)

    def fly(job: Execute) -> None:
        with lock:
            route[:] = list(job.targets)

    link = FleetLink(name, "uav", own, fly, FleetConfig(bid_window_s=2.0))
    link.start(session)
    print("ready", flush=True)
    last = time.monotonic()
    try:
        while True:
            time.sleep(0.05)
            now = time.monotonic()
            with lock:  # fly toward the next target of the share at the robot's speed
                step = speed * (now - last)
                if route:
                    t = route[0]
                    d = horizontal_m(pos[0], pos[1], t.lat, t.lon)
                    k = 1.0 if d <= step else step / d
                    pos[0] += (t.lat - pos[0]) * k
                    pos[1] += (t.lon - pos[1]) * k
                    if d <= step:
                        route.pop(0)
            last = now
            link.tick()
    except KeyboardInterrupt:
        return 0
    finally:
        link.stop()
        token.undeclare()
        session.close()


def bus_trial(rng: random.Random, trial: int, robots: int = BUS_ROBOTS, n_targets: int = BUS_TARGETS
              ) -> dict[str, float]:
    """``robots`` agents meshed over real routers: allocation time over the bus, then re-allocation after a kill."""
    procs: list[subprocess.Popen] = []
    here = str(Path(__file__).resolve())
    try:
        ports = [free_port() for _ in range(robots)]
        routers = []
        for i, p in enumerate(ports):
            cmd = [sys.executable, "-m", "bbcs.router", "--listen", f"tcp/127.0.0.1:{p}"]
            if i:
                cmd += ["--connect", f"tcp/127.0.0.1:{ports[0]}"]
            routers.append(subprocess.Popen(cmd, env=child_env(), start_new_session=True,
                                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            wait_port(p, 30)
        procs += routers
        agents = []
        for i, p in enumerate(ports):
            a = subprocess.Popen([sys.executable, here, "--agent", f"r{i:02d}", "--port", str(p),
                                  "--north", str(rng.uniform(0, 1000)), "--east", str(rng.uniform(0, 1000)),
                                  "--speed", str(rng.uniform(20, 40))], env=child_env(), stdout=subprocess.PIPE,
                                 text=True, start_new_session=True)
            agents.append(a)
            procs.append(a)
        for a in agents:
            assert a.stdout is not None and a.stdout.readline().strip() == "ready"
        session = open_session(local_client(ports[-1]))
        view = FleetView(session)
        try:
            names = {f"r{i:02d}" for i in range(robots)}
            deadline = time.monotonic() + 30
            while len(list(session.liveliness().get(keys.alive_pattern("*", "ral"), timeout=2.0))) < robots:
                assert time.monotonic() < deadline, "the agents' liveliness tokens not all seen"
                time.sleep(0.2)
            targets = [FleetTarget(id=f"t{i:02d}", lat=LAT0 + rng.uniform(0, 1000) * M_LAT,
                                   lon=LON0 + rng.uniform(0, 1000) * M_LAT / math.cos(math.radians(LAT0)), alt=ALT)
                       for i in range(n_targets)]
            task = FleetTask(id=f"bench{trial}", targets=targets)
            posted = time.time()
            view.post(task)
            first = view.wait(lambda: view.agreed(task.id, names), 30)
            assert first is not None, f"no agreement: {view.decisions(task.id)}"
            alloc_ms = (max(d.decided for d in view.decisions(task.id).values()) - posted) * 1000
            # the agent holding most targets, but never r00: every other router meshes through its router, so
            # killing it would partition the rest (a partition is docs/fleet.md's case, not this measurement)
            victim = max((r for r in first.routes if r != "r00"), key=lambda r: (len(first.routes[r]), r))
            vi = int(victim[1:])
            killed = time.time()
            for proc in (agents[vi], routers[vi]):
                os.killpg(proc.pid, signal.SIGKILL)
            survivors = names - {victim}
            after = view.wait(lambda: (d := view.agreed(task.id, survivors)) is not None and d.round >= 1 and d, 30)
            assert after, f"no re-allocation: {view.decisions(task.id)}"
            realloc_s = max(view.decisions(task.id)[r].decided for r in survivors) - killed
            lost = set(first.routes[victim]) - view.visited(task.id)
            placed = {t for r in survivors for t in after.routes[r]}
            assert lost <= placed, (lost, after.routes)
            return {"alloc_bus_ms": alloc_ms, "realloc_s": realloc_s, "lost_targets": len(lost),
                    "victim_targets": len(first.routes[victim])}
        finally:
            view.close()
            session.close()
    finally:
        for proc in reversed(procs):
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGTERM)
                stop_process(proc, 5)


def _descendants(root: int) -> list[int]:
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rpartition(")")[2].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [root]
    while todo:
        pid = todo.pop()
        out.append(pid)
        todo += children.get(pid, [])
    return out


def _cpu_s(pids: list[int]) -> float:
    total = 0
    for pid in pids:
        try:
            f = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
            total += int(f[11]) + int(f[12])
        except (OSError, IndexError, ValueError):
            continue
    return total / os.sysconf("SC_CLK_TCK")


def scale_measure(window_s: float) -> dict[str, float]:
    """cromat fleet bbcs_conf/fleet10_sim.toml with a ground station on the hub watching every robot's GRI state
    and the fleet states: CPU per robot (all its processes) and the payload bytes per robot that cross the mesh
    to that station (Zenoh's framing and router-to-router traffic not counted: /proc io does not see socket
    recv/send)."""
    import tempfile

    from bbcs.contracts import gri
    from module_manager.fleet import Fleet, load_fleet

    spec = load_fleet(Path(__file__).resolve().parents[1] / "bbcs_conf" / "fleet10_sim.toml")
    with tempfile.TemporaryDirectory() as run:
        fleet = Fleet(spec, Path(run), out=lambda _s: None)
        try:
            fleet.start()
            session = open_session(local_client(fleet.hub_port))
            seen = {"gri": [0, 0], "fleet": [0, 0]}

            def count(kind: str):  # type: ignore[no-untyped-def]
                def on_sample(sample) -> None:  # type: ignore[no-untyped-def]
                    seen[kind][0] += 1
                    seen[kind][1] += len(sample.payload.to_bytes())
                return on_sample

            subs = [session.declare_subscriber(gri.state_key("*"), count("gri")),
                    session.declare_subscriber(keys.fleet_state_key("*"), count("fleet"))]
            time.sleep(5.0)  # let the ground station's subscriptions settle before the window
            assert fleet.hub is not None
            robots = [_descendants(p.pid) for p in fleet.procs]
            for v in seen.values():
                v[:] = [0, 0]
            cpu0, t0 = [_cpu_s(p) for p in robots], time.monotonic()
            hub_cpu0 = _cpu_s([fleet.hub.pid])
            time.sleep(window_s)
            dt = time.monotonic() - t0
            cpu = [(_cpu_s(p) - c) / dt for p, c in zip(robots, cpu0, strict=True)]
            hub_cpu = (_cpu_s([fleet.hub.pid]) - hub_cpu0) / dt
            n = spec.robots
            for sub in subs:
                sub.undeclare()
            session.close()
            return {"robots": n, "window_s": round(dt, 1), "cpu_per_robot_mean": statistics.fmean(cpu),
                    "cpu_per_robot_max": max(cpu), "hub_cpu": hub_cpu,
                    "gri_state_bytes_per_s_per_robot": seen["gri"][1] / dt / n,
                    "gri_state_bytes": seen["gri"][1] / max(1, seen["gri"][0]),
                    "fleet_state_bytes_per_s_per_robot": seen["fleet"][1] / dt / n,
                    "fleet_state_bytes": seen["fleet"][1] / max(1, seen["fleet"][0])}
        finally:
            fleet.stop()


def clock_offset(smoke: bool = False) -> dict[str, float]:
    """The clock-offset estimator's error over the bus (ral/sync.py, docs/sync.md); ``smoke``: 2 robots, 1 s."""
    from clock_offset import measure_clock_offset_p99_ms

    return measure_clock_offset_p99_ms(n_robots=2, duration_s=1.0) if smoke else measure_clock_offset_p99_ms()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--instances", type=int, default=40, help="random instances per case (default 40)")
    ap.add_argument("--bus-trials", type=int, default=3, help="10-agent trials over the bus (default 3; 0: none)")
    ap.add_argument("--seed", type=int, default=17)
    ap.add_argument("--out", help="results file (default bench/results/fleet.json)")
    ap.add_argument("--scale", type=float, default=0.0, metavar="S",
                    help="also launch bbcs_conf/fleet10_sim.toml and measure CPU and mesh bytes over S seconds")
    ap.add_argument("--agent", help=argparse.SUPPRESS)
    ap.add_argument("--port", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--north", type=float, default=0.0, help=argparse.SUPPRESS)
    ap.add_argument("--east", type=float, default=0.0, help=argparse.SUPPRESS)
    ap.add_argument("--speed", type=float, default=5.0, help=argparse.SUPPRESS)
    ap.add_argument("--smoke", action="store_true",
                    help="2 instances, one bus trial of 3 agents and 6 targets, the clock of 2 robots for 1 s: "
                         "proves the bench still runs (CI)")
    args = ap.parse_args()
    bus_robots, bus_targets = BUS_ROBOTS, BUS_TARGETS
    if args.smoke:
        args.instances, args.bus_trials, args.scale = 2, 1, 0.0
        bus_robots, bus_targets = 3, 6
    if args.agent:
        return agent(args.agent, args.port, args.north, args.east, args.speed)
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
            if n == 10 and targets == 10 and ref_name.startswith("optimum"):
                summary["alloc_cost_ratio_10"] = round(row["ratio_mean"], 4)
                summary["alloc_cost_ratio_max_10"] = round(row["ratio_max"], 4)
                summary["alloc_time_p99_ms_10"] = round(row["alloc_p99_ms"], 3)
    bus_rows = []
    for trial in range(args.bus_trials):
        row = bus_trial(rng, trial, bus_robots, bus_targets)
        bus_rows.append(row)
        print(f"bus trial {trial}: {bus_robots} agents x {bus_targets} targets agreed in {row['alloc_bus_ms']:.0f} ms; "
              f"{row['victim_targets']} targets of the killed agent ({row['lost_targets']} unvisited) "
              f"re-allocated in {row['realloc_s']:.3f} s")
    summary["realloc_s_10"] = round(max(r["realloc_s"] for r in bus_rows), 3) if bus_rows else None
    summary["alloc_bus_ms_10"] = round(max(r["alloc_bus_ms"] for r in bus_rows), 1) if bus_rows else None
    clock = clock_offset(args.smoke)
    summary["clock_offset_p99_ms"] = round(clock["clock_offset_p99_ms"], 3)
    print("clock offset over the bus (ral/sync.py): " + ", ".join(f"{k} {v:.3g}" for k, v in clock.items()))
    scale = None
    if args.scale > 0:
        scale = scale_measure(args.scale)
        print("scale, 10 robots (cromat fleet) + a ground station on the hub watching all: "
              + ", ".join(f"{k} {v:.3g}" for k, v in scale.items()))
        summary["mesh_bytes_per_s_per_robot"] = round(scale["gri_state_bytes_per_s_per_robot"]
                                                      + scale["fleet_state_bytes_per_s_per_robot"])
        summary["cpu_per_robot"] = round(scale["cpu_per_robot_mean"], 3)
    notes = {
        "alloc_cost_ratio_10": "mean over random instances of auction cost / linear_sum_assignment optimum, 10 robots "
                               "x 10 targets, one target per robot, same cost matrix",
        "alloc_time_p99_ms_10": "p99 of one in-process allocation, 10 robots x 10 targets (one per robot)",
        "realloc_s_10": "worst of the bus trials: 10 agent processes (the RAL's FleetLink, each on its own router, "
                        "routers meshed), time from SIGKILL of the agent holding most targets (and its router) to "
                        "the last survivor's decision of the new round, all survivors agreeing (one machine clock)",
        "alloc_bus_ms_10": "worst of the bus trials: from the ground station's put of 30 targets to the last of 10 "
                           "agents' decision (all agreeing)",
        "clock_offset_p99_ms": "the RAL's clock-offset estimator (bench/clock_offset.py: robots "
                               "with skewed, drifting clocks on meshed routers, |estimate - truth|)",
    }
    write_results("fleet", {"summary": summary, "notes": notes, "rows": rows, "bus_trials": bus_rows,
                            "scale": scale, "clock": clock,
                            "instances": args.instances, "seed": args.seed}, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
