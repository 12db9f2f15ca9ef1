"""Route swap latency: from sending the MRI ``route`` request to the first datum from the new source that the
receiving module handles (p50/p99), against the round trip of a no-op MRI request measured in the same run.

Runs the module-manager test robot (tests/module_manager/probe_robot.toml: two sources publishing every
``--period-ms``, one sink recording what it handles with a timestamp) and swaps the sink between them.

    python bench/slot_swap.py [--swaps 100] [--period-ms 1]

Writes bench/results/slot_swap.json with summary keys ``swap_p50_ms`` and ``swap_p99_ms``.
"""

from __future__ import annotations

import argparse
import json
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

from benchlib import ROOT, pct, work_dir, write_results

from bbcs import local_client, open_session
from bbcs.contracts import mri
from bbcs.testing import child_env, free_port

PROBE = ROOT / "tests" / "module_manager"


def records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.endswith("}")]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--swaps", type=int, default=100)
    ap.add_argument("--period-ms", type=float, default=1.0, help="source publishing period")
    ap.add_argument("--out", help="result file (default bench/results/slot_swap.json)")
    ap.add_argument("--smoke", action="store_true", help="4 swaps: proves the bench still runs (CI)")
    args = ap.parse_args(argv)
    if args.smoke:
        args.swaps = 4
    with work_dir("cromat-swap-") as work:
        return run(args, work)


def run(args: argparse.Namespace, work: Path) -> int:
    """The benchmark in ``work`` (removed when it ends well, kept with its logs when it fails)."""
    text = (PROBE / "probe_robot.toml").read_text()
    text = text.replace('pythonpath = ["."]', f'pythonpath = ["{PROBE}"]')
    text = text.replace('conf = "probe_robot.conf"', f'conf = "{PROBE / "probe_robot.conf"}"')
    text = text.replace('period_ms = "5"', f'period_ms = "{args.period_ms:g}"')
    manifest = work / "robot.toml"
    manifest.write_text(text)
    port = free_port()
    env = child_env()
    proc = subprocess.Popen([sys.executable, "-m", "module_manager.cli", str(manifest), "--listen",
                             f"tcp/127.0.0.1:{port}"], cwd=str(ROOT), env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, start_new_session=True)
    session = None
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if "all 3 modules up" in line:
                break
        else:
            raise SystemExit("the probe robot did not come up")
        session = open_session(local_client(port))
        rec = work / "sink.jsonl"
        noop, swaps, acks = [], [], []
        slot = 1
        for _ in range(args.swaps):
            t0 = time.perf_counter()
            mri.call(session, "r1", "routes", mri.ListRoutes())
            noop.append((time.perf_counter() - t0) * 1000)
            slot = 2 if slot == 1 else 1
            want = "src_b" if slot == 2 else "src_a"
            n = len(records(rec))
            sent = time.time()
            t0 = time.perf_counter()
            reply = mri.call(session, "r1", "route", mri.SwapRoute(module="sink", input="datos", slot=slot))
            acks.append((time.perf_counter() - t0) * 1000)
            if not reply.ok:
                raise SystemExit(f"swap refused: {reply.reason}")
            first = None
            deadline = time.monotonic() + 5
            while first is None and time.monotonic() < deadline:
                first = next((r for r in records(rec)[n:] if r.get("source") == want), None)
                if first is None:
                    time.sleep(0.005)
            if first is None:
                raise SystemExit("no datum from the new source after a swap")
            swaps.append((first["t"] - sent) * 1000)
            time.sleep(0.02)
    finally:
        if session is not None:
            session.close()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        proc.wait(30)
        if proc.stdout is not None:
            proc.stdout.close()
    p50, p99 = statistics.median(swaps), pct(swaps, 99)
    print(f"{'measure (ms)':<46} {'p50':>7} {'p99':>7} {'max':>7}")
    print(f"{'MRI route swap -> first new-source datum used':<46} {p50:7.2f} {p99:7.2f} {max(swaps):7.2f}")
    print(f"{'MRI route swap -> acknowledged reply':<46} {statistics.median(acks):7.2f} {pct(acks, 99):7.2f} "
          f"{max(acks):7.2f}")
    print(f"{'baseline: MRI no-op (routes) round trip':<46} {statistics.median(noop):7.2f} {pct(noop, 99):7.2f} "
          f"{max(noop):7.2f}")
    write_results("slot_swap", {
        "swaps": args.swaps, "source_period_ms": args.period_ms,
        "swap_ms": [round(v, 3) for v in swaps], "ack_ms": [round(v, 3) for v in acks],
        "noop_mri_ms": [round(v, 3) for v in noop],
        "baseline_noop_p50_ms": round(statistics.median(noop), 3),
        "summary": {"swap_p50_ms": round(p50, 3), "swap_p99_ms": round(p99, 3)}}, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
