"""Lidar log writers: throughput against the LD-MRS real-time rate, CPU share at real time, bytes per minute.

The LD-MRS sends about 700 points every 80 ms (seed ch. 4.2.2.1): 8,750 points/s. One minute of flight
(750 scans of ~700 points, from the simulator scanning the synthetic terrain, with real poses) is written by

- the text writer (Figure 42 format, ``textlog.TextLogWriter``) and, as its baseline in the same run, a
  naive text writer that formats and writes one point line at a time (the straightforward port of the
  seed's processScan);
- the binary writer (``binlog.BinaryLogWriter``, compressed per scan) and, as its baseline, a raw dump of
  every scan's wire payload (the least work any binary log can do).

Throughput = points / CPU seconds of the writer; real-time factor = throughput / 8,750; CPU share at real
time = 8,750 / throughput (fraction of one core). Reading back (text parse, binary load) is timed too.

    python bench/lidar.py            # ~20 s; table on stdout, JSON in bench/results/lidar.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from benchlib import write_results

from modules.lidar_logger.binlog import BinaryLogWriter, read_binary_log
from modules.lidar_logger.flags import wire_to_seed
from modules.lidar_logger.ldmrs_scan import encode_scan
from modules.lidar_logger.logdata import ScanRecord
from modules.lidar_logger.sim import LdmrsDevice, LdmrsOptions, World
from modules.lidar_logger.textlog import TextLogWriter, format_scan, read_text_log

REALTIME_POINTS_PER_S = 700 / 0.080
SCANS_PER_MINUTE = 750


def make_flight(n_scans: int, seed: int) -> list[ScanRecord]:
    """``n_scans`` simulator scans of about 700 points each, with the pose of their time attached."""
    world = World()
    device = LdmrsDevice(world, LdmrsOptions(return_fraction=0.47, seed=seed))
    device.params[0x1012] = 0xFFEE
    device.params[0x1104] = 1
    device.handle_command(b"\x20\x00\x03\x00", 10.0)  # StartMeasure at t = 10 s
    records = []
    t = 10.0
    while len(records) < n_scans:
        t += device.period
        while device.due(t):
            scan = device.take_scan(send=True)
            records.append(ScanRecord(len(records) + 1, scan, world.true_pose(t)))
    return records[:n_scans]


class NaiveTextWriter:
    """Baseline: the same bytes, but one formatted line and one write() per point."""

    def __init__(self, path: Path) -> None:
        self.f = open(path, "x", encoding="ascii")  # noqa: SIM115

    def write(self, record: ScanRecord) -> None:
        scan, f = record.scan, self.f
        empty = ScanRecord(record.index, dataclasses.replace(scan, points=scan.points[:0]), record.pose)
        f.write(format_scan(empty)[:-2].replace("Points 0\n", f"Points {scan.n_points}\n"))
        xyz, flags = scan.cartesian(), wire_to_seed(scan.wire_flags)
        width, layer, echo, off = scan.echo_width_cm, scan.layer, scan.echo, scan.time_offsets_us()
        for i in range(scan.n_points):
            f.write(f"{i + 1}; {xyz[i, 0]:.8f},{xyz[i, 1]:.8f},{xyz[i, 2]:.8f}; {width[i] / 100:.2f}; "
                    f"{flags[i]}; {layer[i]}; {echo[i]}; {off[i]}; {int(flags[i] == 0)}; 0\n")
        f.write("\n\n")
        f.flush()

    def close(self) -> None:
        self.f.close()


class RawWireWriter:
    """Baseline: append each scan's 0x2202 payload as received, nothing else."""

    def __init__(self, path: Path) -> None:
        self.f = open(path, "xb")  # noqa: SIM115

    def write(self, record: ScanRecord) -> None:
        self.f.write(encode_scan(record.scan))
        self.f.flush()

    def close(self) -> None:
        self.f.close()


def time_writer(make, records: list[ScanRecord], folder: Path, repeats: int) -> dict[str, float]:
    """Best of ``repeats`` runs: CPU and wall seconds, and the bytes written."""
    best_cpu = best_wall = float("inf")
    size = 0
    for k in range(repeats):
        base = folder / f"run{k}_{make.__name__}"
        cpu0, wall0 = time.process_time(), time.perf_counter()
        writer = make(base)
        for r in records:
            writer.write(r)
        writer.close()
        best_cpu = min(best_cpu, time.process_time() - cpu0)
        best_wall = min(best_wall, time.perf_counter() - wall0)
        size = sum(p.stat().st_size for p in folder.glob(base.name + "*"))
    points = sum(r.scan.n_points for r in records)
    return {"cpu_s": best_cpu, "wall_s": best_wall, "bytes": size, "points": points,
            "points_per_s": points / best_cpu, "realtime_factor": points / best_cpu / REALTIME_POINTS_PER_S,
            "cpu_share_at_realtime": REALTIME_POINTS_PER_S * best_cpu / points}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=SCANS_PER_MINUTE, help="scans written (750 = one minute)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--out", help="result file (default bench/results/lidar.json)")
    ap.add_argument("--smoke", action="store_true", help="20 scans, one run each: proves the bench still runs (CI)")
    args = ap.parse_args(argv)
    if args.smoke:
        args.scans, args.repeats = 20, 1

    t0 = time.perf_counter()
    records = make_flight(args.scans, args.seed)
    points = sum(r.scan.n_points for r in records)
    print(f"flight: {len(records)} scans, {points} points ({points / len(records):.0f} per scan), "
          f"built in {time.perf_counter() - t0:.1f} s; real time = {REALTIME_POINTS_PER_S:.0f} points/s")

    with tempfile.TemporaryDirectory(prefix="bench_lidar_") as tmp:
        folder = Path(tmp)
        results = {
            "text": time_writer(TextLogWriter, records, folder, args.repeats),
            "text_naive_baseline": time_writer(NaiveTextWriter, records, folder, args.repeats),
            "binary": time_writer(lambda p: BinaryLogWriter(p), records, folder, args.repeats),
            "raw_wire_baseline": time_writer(RawWireWriter, records, folder, args.repeats),
        }
        text_file = next(f for f in folder.glob("run0_TextLogWriter*"))
        naive_file = next(f for f in folder.glob("run0_NaiveTextWriter*"))
        if text_file.read_bytes() != naive_file.read_bytes():
            raise SystemExit("the naive baseline did not write the same text: the comparison would be unfair")
        bin_file = next(folder.glob("run0_*.scans.bin"))
        c0 = time.process_time()
        read_text_log(text_file)
        text_read = time.process_time() - c0
        c0 = time.process_time()
        read_binary_log(bin_file)
        bin_read = time.process_time() - c0
    per_minute = SCANS_PER_MINUTE / len(records)
    for r in results.values():
        r["bytes_per_minute"] = r["bytes"] * per_minute
    results["text"]["read_points_per_s"] = points / text_read
    results["binary"]["read_points_per_s"] = points / bin_read

    summary = {
        "text_realtime_factor": results["text"]["realtime_factor"],
        "binary_realtime_factor": results["binary"]["realtime_factor"],
        "text_to_binary_size_ratio": results["text"]["bytes"] / results["binary"]["bytes"],
    }
    print(f"\n{'writer':<22}{'points/s':>12}{'x real time':>13}{'CPU at RT':>11}{'MB/min':>9}")
    for name, r in results.items():
        print(f"{name:<22}{r['points_per_s']:>12,.0f}{r['realtime_factor']:>13.1f}"
              f"{r['cpu_share_at_realtime']:>11.2%}{r['bytes_per_minute'] / 1e6:>9.2f}")
    speedup = results["text"]["points_per_s"] / results["text_naive_baseline"]["points_per_s"]
    raw_ratio = results["binary"]["bytes"] / results["raw_wire_baseline"]["bytes"]
    print(f"\ntext writer vs naive baseline: {speedup:.2f}x faster; binary log vs raw wire dump: "
          f"{raw_ratio:.2f}x the bytes")
    print(f"reading back: text {results['text']['read_points_per_s']:,.0f} points/s, "
          f"binary {results['binary']['read_points_per_s']:,.0f} points/s")
    print(f"summary: {json.dumps(summary)}")
    write_results("lidar", {"summary": summary, "realtime_points_per_s": REALTIME_POINTS_PER_S,
                            "scans": len(records), "points": points, "writers": results,
                            "cpus": os.cpu_count()}, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
