"""Cold start of the sim UAV manifest to all modules up (median of 5), against the honest floor measured in the
same run: the same number of processes started at once, each importing what its module (or process) imports and,
for the modules and the router, opening a Zenoh session to a router. The old baseline (as many bare
``python -c "import zenoh"``) is kept as ``cold_start_ratio_bare``.

    python bench/launch.py [--manifest bbcs_conf/uav1_sim.toml] [--runs 5] [--no-bytecode-cache]

Every process runs with Python's bytecode cache on (``PYTHONDONTWRITEBYTECODE`` removed from the children's
environment) after one untimed launch that writes it: a robot's installed package has its ``.pyc`` files, and
without them each process compiles every source it imports, which then weighs more than the launch itself. With
``--no-bytecode-cache`` the children inherit the environment as it is (on a machine that sets
``PYTHONDONTWRITEBYTECODE``, everything compiled on every start) and there is no warm-up.

Writes bench/results/launch.json with summary keys ``cold_start_s``, ``floor_s``, ``cold_start_ratio`` (launch over
the floor; target ≤ 1.5) and ``cold_start_ratio_bare``.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

from benchlib import ROOT, write_results

from bbcs.testing import child_env, free_port, wait_port
from module_manager.manifest import Manifest, load_manifest

FLOOR_CHILD = """
import importlib, sys
for name in sys.argv[2:]:
    if name.startswith("entry:"):  # what a standby preloads: the entry's __main__ top-level imports
        from module_manager.standby import preload
        preload(name[6:])
    else:
        importlib.import_module(name)
if sys.argv[1]:
    import zenoh
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", '["' + sys.argv[1] + '"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    zenoh.open(conf).close()
"""
"""One floor process: import the given modules, then (if an endpoint is given) open and close a Zenoh session."""


BYTECODE_CACHE = True
"""Children keep Python's bytecode cache (``--no-bytecode-cache`` turns it off: the environment as it is)."""


def bench_env(**extra: str) -> dict[str, str]:
    """The children's environment: ``child_env`` without ``PYTHONDONTWRITEBYTECODE`` unless told otherwise."""
    env = child_env(**extra)
    if BYTECODE_CACHE:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def cold_start(manifest: Path, expect: str) -> float:
    """Seconds from starting ``cromat launch`` to its "all N modules up" line; it then stops everything."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "module_manager.cli", str(manifest), "--once-up",
                             "--listen", f"tcp/127.0.0.1:{free_port()}"], cwd=str(ROOT), env=bench_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    up = None
    said: list[str] = []
    assert proc.stdout is not None
    for line in proc.stdout:
        said.append(line.rstrip())
        if expect in line and up is None:
            up = time.perf_counter() - t0
    proc.wait(60)
    proc.stdout.close()
    if up is None or proc.returncode != 0:
        tail = "\n".join(said[-40:])
        raise SystemExit(f"cromat launch did not come up (exit {proc.returncode}); what it said:\n{tail}")
    return up


def bare_zenoh(n: int) -> float:
    """Seconds to start ``n`` ``python -c "import zenoh"`` processes at once and see them all finish."""
    t0 = time.perf_counter()
    procs = [subprocess.Popen([sys.executable, "-c", "import zenoh"], env=bench_env()) for _ in range(n)]
    for p in procs:
        p.wait(60)
    return time.perf_counter() - t0


def floor_jobs(m: Manifest) -> list[list[str]]:
    """Per process of the launch, what it imports: each module's class module and what ``python -m entry``
    imports before it runs (its ``__main__``'s top-level imports, as a standby preloads them), each ``-m``
    process's module, and zenoh for the router."""
    jobs = [["zenoh"]]  # the router
    for proc in m.raw.processes.values():
        cmd = proc.command
        jobs.append([cmd[cmd.index("-m") + 1]] if "-m" in cmd else [])
    jobs += [[info.spec.cls.partition(":")[0], f"entry:{info.spec.entry}"] for info in m.modules.values()]
    return jobs


def floor(m: Manifest, endpoint: str) -> float:
    """Seconds to start the floor's processes at once and see them all finish (modules and router: with a session
    opened to the router at ``endpoint``)."""
    env = bench_env(PYTHONPATH=":".join([str(p) for p in m.pythonpath] + [str(ROOT)]))
    jobs = floor_jobs(m)
    n_sessions = 1 + len(m.modules)
    t0 = time.perf_counter()
    procs = [subprocess.Popen([sys.executable, "-c", FLOOR_CHILD, endpoint if i == 0 or i > len(jobs) - n_sessions
                               else "", *job], env=env, cwd=str(m.dir)) for i, job in enumerate(jobs)]
    for p in procs:
        p.wait(60)
    if any(p.returncode for p in procs):
        raise SystemExit(f"a floor process failed: {[p.returncode for p in procs]}")
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--manifest", default=str(ROOT / "bbcs_conf" / "uav1_sim.toml"))
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--no-bytecode-cache", action="store_true",
                    help="children inherit the environment as it is, no warm-up launch (see the module's doc)")
    ap.add_argument("--out", help="result file (default bench/results/launch.json)")
    ap.add_argument("--smoke", action="store_true", help="one timed run, no warm-up: proves it runs (CI)")
    args = ap.parse_args(argv)
    if args.smoke:
        args.runs = 1
    global BYTECODE_CACHE
    BYTECODE_CACHE = not args.no_bytecode_cache
    manifest = Path(args.manifest).resolve()
    m = load_manifest(manifest)
    n_modules = len(m.modules)
    n_procs = n_modules + len(m.raw.processes) + 1  # + the router
    port = free_port()
    router = subprocess.Popen([sys.executable, "-m", "bbcs.router", "--listen", f"tcp/127.0.0.1:{port}"],
                              cwd=str(ROOT), env=bench_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    launches, floors, bares = [], [], []
    try:
        wait_port(port, 30)
        if BYTECODE_CACHE and not args.smoke:  # untimed: writes the .pyc files of what the launch and floor import
            cold_start(manifest, f"all {n_modules} modules up")
            floor(m, f"tcp/127.0.0.1:{port}")
        for _ in range(args.runs):
            launches.append(cold_start(manifest, f"all {n_modules} modules up"))
            floors.append(floor(m, f"tcp/127.0.0.1:{port}"))
            bares.append(bare_zenoh(n_procs))
    finally:
        router.terminate()
        router.wait(30)
    cold, low, bare = statistics.median(launches), statistics.median(floors), statistics.median(bares)
    ratio, ratio_bare = cold / low, cold / bare
    print(f"{'measure':<42} {'median s':>9} {'min s':>7} {'max s':>7}")
    print(f"{f'cromat launch {manifest.name} ({n_procs} procs)':<42} {cold:9.3f} {min(launches):7.3f} "
          f"{max(launches):7.3f}")
    print(f"{f'floor: {n_procs} x imports + zenoh session':<42} {low:9.3f} {min(floors):7.3f} {max(floors):7.3f}")
    print(f"{f'{n_procs} x python -c import zenoh':<42} {bare:9.3f} {min(bares):7.3f} {max(bares):7.3f}")
    print(f"cold_start_ratio {ratio:.2f} (over the floor), cold_start_ratio_bare {ratio_bare:.2f}; bytecode cache "
          f"{'on' if BYTECODE_CACHE else 'as the environment says'}")
    write_results("launch", {
        "manifest": str(manifest.relative_to(ROOT)) if manifest.is_relative_to(ROOT) else str(manifest),
        "runs": args.runs, "processes": n_procs, "bytecode_cache": BYTECODE_CACHE, "launch_s": launches,
        "floor_s": floors,
        "bare_import_zenoh_s": bares, "floor_imports": floor_jobs(m),
        "summary": {"cold_start_s": round(cold, 4), "floor_s": round(low, 4), "cold_start_ratio": round(ratio, 3),
                    "cold_start_ratio_bare": round(ratio_bare, 3)}}, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
