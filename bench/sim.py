"""Lockstep simulation (docs/simulation.md, "Lockstep"): how fast, and whether a loaded machine changes the flight.

1. ``survey_sim_speedup``: the shipped ``bbcs_conf/uav1_lidar_sim.toml`` in lockstep at ``--speed max`` (the DSP
   simulator stepping on the barrier; the MTi-G/LD-MRS simulators following its truth), take-off, the survey of
   the shipped area ``bbcs_conf/uav1_survey_area.geojson`` (71 m x 89 m, 25 m, 10 % overlap), landing: simulated
   seconds (the GRI state's stamps) over wall seconds, from the take-off request to the GRI's "on the ground".
   Target: >= 10 on this 2-core machine.
2. ``lockstep_same_record``: the shipped ``bbcs_conf/uav1_sim.toml`` in lockstep, take-off, a goto, landing and
   20 simulated seconds of watching, once on the machine as it is and once beside 4 processes spinning on a
   processor each: the simulated DSP's two records, as command sequence and fields, are identical.

    python bench/sim.py                  # both, about 2-3 minutes; table on stdout, JSON in bench/results/sim.json
    python bench/sim.py --only survey    # or: --only record
    python bench/sim.py --smoke          # take-off and landing in lockstep only (the suite's check that it runs)
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from benchlib import ROOT, write_results

sys.path.insert(0, str(ROOT / "tests" / "system"))
from lockstep_support import Flight, busy_processes, fly_mission, fly_survey, stop  # noqa: E402

SPEEDUP_TARGET = 10.0


def describe(flight: Flight) -> dict[str, object]:
    return {"sim_s": round(flight.sim_s, 2), "wall_s": round(flight.wall_s, 2),
            "speedup": round(flight.sim_s / flight.wall_s, 2) if flight.wall_s > 0 else None,
            "commands": len(flight.record), "tasks": flight.events,
            "cpu_s": {k: round(v, 1) for k, v in sorted((flight.cpu_s or {}).items(), key=lambda kv: -kv[1])}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("survey", "record"), help="run one of the two measurements")
    ap.add_argument("--busy", type=int, default=4, help="busy processes beside the second mission (4)")
    ap.add_argument("--out", help="result file (default bench/results/sim.json)")
    ap.add_argument("--smoke", action="store_true",
                    help="take-off and landing on the survey robot only (seconds): the suite's check that it runs")
    args = ap.parse_args(argv)
    if args.smoke:
        args.only = "survey"
    result: dict[str, object] = {}
    summary: dict[str, object] = {}
    rows: list[tuple[str, str]] = []
    with tempfile.TemporaryDirectory(prefix="cromat-bench-sim-") as tmp:
        if args.only in (None, "survey"):
            survey = fly_survey(Path(tmp) / "survey", survey=not args.smoke)
            result["survey"] = describe(survey)
            speedup = survey.sim_s / survey.wall_s
            label = "smoke_sim_speedup" if args.smoke else "survey_sim_speedup"  # take-off + landing: no contract
            summary[label] = round(speedup, 2)
            rows.append((label, f"{speedup:.2f}x ({survey.sim_s:.1f} s simulated in "
                                               f"{survey.wall_s:.1f} s; target >= {SPEEDUP_TARGET:g})"))
            rows.append(("survey tasks", ", ".join(survey.events)))
        if args.only in (None, "record"):
            quiet = fly_mission(Path(tmp) / "quiet")
            hogs = busy_processes(args.busy)
            try:
                loaded = fly_mission(Path(tmp) / "loaded")
            finally:
                stop(hogs)
            same = quiet.commands() == loaded.commands() and quiet.events == loaded.events
            result["mission_quiet"] = describe(quiet)
            result["mission_loaded"] = describe(loaded) | {"busy_processes": args.busy}
            summary["lockstep_same_record"] = same
            summary["mission_speedup_quiet"] = round(quiet.sim_s / quiet.wall_s, 2)
            summary["mission_speedup_loaded"] = round(loaded.sim_s / loaded.wall_s, 2)
            rows.append(("lockstep_same_record", f"{str(same).lower()} ({len(quiet.record)} commands each)"))
            rows.append(("mission speedup", f"{quiet.sim_s / quiet.wall_s:.2f}x quiet, "
                                            f"{loaded.sim_s / loaded.wall_s:.2f}x beside {args.busy} busy processes"))
    result["summary"] = summary
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        print(f"{key:<{width}}  {value}")
    write_results("sim", result, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
