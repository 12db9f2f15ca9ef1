"""Cold start of the sim UAV manifest to all modules alive (median of 5), against starting the same number of bare
``python -c "import zenoh"`` processes at once, measured in the same run.

    python bench/launch.py [--manifest bbcs_conf/uav1_sim.toml] [--runs 5]

Writes bench/results/launch.json with summary keys ``cold_start_s`` and ``cold_start_ratio``.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

from benchlib import ROOT, write_results

from bbcs.testing import child_env, free_port
from module_manager.manifest import load_manifest


def cold_start(manifest: Path, expect: str) -> float:
    """Seconds from starting ``cromat launch`` to its "all N modules up" line; it then stops everything."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "module_manager.cli", str(manifest), "--once-up",
                             "--listen", f"tcp/127.0.0.1:{free_port()}"], cwd=str(ROOT), env=child_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, start_new_session=True)
    up = None
    assert proc.stdout is not None
    for line in proc.stdout:
        if expect in line:
            up = time.perf_counter() - t0
    proc.wait(60)
    proc.stdout.close()
    if up is None or proc.returncode != 0:
        raise SystemExit(f"cromat launch did not come up (exit {proc.returncode})")
    return up


def bare_zenoh(n: int) -> float:
    """Seconds to start ``n`` ``python -c "import zenoh"`` processes at once and see them all finish."""
    t0 = time.perf_counter()
    procs = [subprocess.Popen([sys.executable, "-c", "import zenoh"], env=child_env()) for _ in range(n)]
    for p in procs:
        p.wait(60)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--manifest", default=str(ROOT / "bbcs_conf" / "uav1_sim.toml"))
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args(argv)
    manifest = Path(args.manifest).resolve()
    m = load_manifest(manifest)
    n_modules = len(m.modules)
    n_procs = n_modules + len(m.raw.processes) + 1  # + the router
    launches, bares = [], []
    for _ in range(args.runs):
        launches.append(cold_start(manifest, f"all {n_modules} modules up"))
        bares.append(bare_zenoh(n_procs))
    cold, bare = statistics.median(launches), statistics.median(bares)
    ratio = cold / bare
    print(f"{'measure':<42} {'median s':>9} {'min s':>7} {'max s':>7}")
    print(f"{f'cromat launch {manifest.name} ({n_procs} procs)':<42} {cold:9.3f} {min(launches):7.3f} "
          f"{max(launches):7.3f}")
    print(f"{f'{n_procs} x python -c import zenoh':<42} {bare:9.3f} {min(bares):7.3f} {max(bares):7.3f}")
    print(f"cold_start_ratio {ratio:.2f}")
    write_results("launch", {
        "manifest": str(manifest.relative_to(ROOT)) if manifest.is_relative_to(ROOT) else str(manifest),
        "runs": args.runs, "processes": n_procs, "launch_s": launches, "bare_import_zenoh_s": bares,
        "summary": {"cold_start_s": round(cold, 4), "cold_start_ratio": round(ratio, 3)}})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
