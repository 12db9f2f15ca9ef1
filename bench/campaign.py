"""The randomized mission campaign (issue 31; docs/simulation.md, "Campaign"): seeded sequences of ground-station
tasks, route swaps and faults flown on the shipped manifests in lockstep at ``--speed max``, the flight-safety
monitor as the oracle; prints the sequences run, the simulated hours and the monitor's breaches by kind.

    python bench/campaign.py                          # the default seed and count, under 3 minutes
    python bench/campaign.py --sequences 200 --seed 7 # longer (--budget-s 0: no wall budget)
    python bench/campaign.py --robot uav              # uav1_sim.toml: pan & tilt, route swaps, path modes 1 and 3
    python bench/campaign.py --robot uquad            # uquad1_sim.toml: the quadrotor (invariants 2, 3 and 5)
    python bench/campaign.py --robot survey --steps 'take_off; done s=90; orbit at=1:0 r=25; done s=90'
    python bench/campaign.py --smoke                  # one short sequence (seconds of flight)

Summary keys (bench/results/campaign.json): ``campaign_sequences``, ``campaign_sim_hours``, ``campaign_breaches``,
``campaign_breaches_by_kind``, ``campaign_incidents`` (a robot stuck or not back on the ground), and the wall time.
Exit 1 when the monitor saw a breach or a sequence had an incident: each is printed with its shrunk reproduction.
"""

from __future__ import annotations

import argparse
import signal
import sys
import tempfile
from pathlib import Path

from benchlib import ROOT, write_results

sys.path.insert(0, str(ROOT / "tests" / "campaign"))
from campaign_run import run_campaign  # noqa: E402
from campaign_steps import PROFILES, parse_steps, show_steps  # noqa: E402

DEFAULT_SEQUENCES = 8
DEFAULT_SEED = 31
DEFAULT_BUDGET_S = 140.0
"""Wall seconds after which no new sequence starts (the launch included): the default run ends within 3 minutes
on this loaded 2-core machine however slow it is that day (sequences not run are counted as skipped)."""
SMOKE_BUDGET_S = 75.0
"""--smoke: no launch attempt or sequence starts after this (tests/bench/test_smoke.py stops a run at 110 s)."""
SMOKE_STEPS = "take_off; done s=60; goto to=1:0 h=15 v=8; done s=60"


def _interrupt(signum: int, frame: object) -> None:
    """SIGTERM ends the campaign as Ctrl+C does: every ``finally`` runs, so no launched robot is left behind (one
    was, killed by SIGTERM mid-launch)."""
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", type=int, default=DEFAULT_SEQUENCES, help=f"how many ({DEFAULT_SEQUENCES})")
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED, help=f"campaign seed ({DEFAULT_SEED})")
    ap.add_argument("--robot", default="survey", help="comma-separated robots, sequences dealt in turn: "
                    + ", ".join(f"{k} ({p.manifest})" for k, p in PROFILES.items()) + " (survey)")
    ap.add_argument("--steps", help="fly these steps once instead of generated sequences (a printed reproduction)")
    ap.add_argument("--budget-s", type=float, default=DEFAULT_BUDGET_S,
                    help=f"wall seconds after which no sequence starts ({DEFAULT_BUDGET_S:g}; 0: none)")
    ap.add_argument("--shrink", type=int, default=4, help="runs spent shrinking each failing sequence (4)")
    ap.add_argument("--smoke", action="store_true", help="one short sequence: the bench still runs")
    ap.add_argument("--keep", help="keep the robots' logs and DSP records in this folder")
    ap.add_argument("--out", help="result file (default bench/results/campaign.json)")
    args = ap.parse_args(argv)
    try:
        profiles = [PROFILES[name] for name in args.robot.split(",")]
        given = parse_steps(SMOKE_STEPS if args.smoke else args.steps) if (args.smoke or args.steps) else None
    except (KeyError, ValueError) as exc:
        ap.error(f"{exc}")
    if args.sequences < 1:
        ap.error("--sequences must be at least 1")
    signal.signal(signal.SIGTERM, _interrupt)  # the robots it launched are stopped, as on Ctrl+C

    try:
        with tempfile.TemporaryDirectory(prefix="cromat-campaign-") as tmp:
            workdir = Path(args.keep) if args.keep else Path(tmp)
            budget = SMOKE_BUDGET_S if args.smoke else args.budget_s or None
            result = run_campaign(args.seed, 0 if given else args.sequences, profiles, workdir, budget_s=budget,
                                  shrink_budget=0 if args.smoke else args.shrink, given=[given] if given else [])
    except KeyboardInterrupt:
        print("campaign interrupted: its robots stopped, no result written", file=sys.stderr)
        return 130
    summary = result.summary()
    rows = [("sequences run", f"{summary['campaign_sequences']}" + (f" ({result.skipped} not run: wall budget)"
                                                                   if result.skipped else "")),
            ("simulated hours", f"{summary['campaign_sim_hours']:.3f} ({result.sim_s:.0f} s, flown at "
                                f"{summary['campaign_sim_speed']}x; {result.wall_s:.0f} s wall, launches "
                                f"{result.launches})"),
            ("breaches", str(summary["campaign_breaches"]))]
    rows += [(f"  {kind}", str(n)) for kind, n in summary["campaign_breaches_by_kind"].items()]
    rows.append(("incidents", str(summary["campaign_incidents"])))
    width = max(len(k) for k, _ in rows)
    print()
    for key, value in rows:
        print(f"{key:<{width}}  {value}")
    for failure in result.failures:
        print()
        print(failure.report())
    if given is not None:
        print(f"\nsteps flown: {show_steps(given)}")
    write_results("campaign", {"summary": summary, "robots": [p.manifest for p in profiles],
                               "sequences": result.sequences,
                               "failures": [f.report() for f in result.failures]}, args.out)
    return 1 if result.failures else 0


if __name__ == "__main__":
    sys.exit(main())
