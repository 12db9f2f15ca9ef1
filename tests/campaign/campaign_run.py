"""The randomized mission campaign (issue 31; docs/simulation.md, "Campaign"): seeded sequences of ground-station
tasks and faults flown on launched robots in lockstep, the flight-safety monitor as the oracle, each failing
sequence shrunk to a short reproduction. ``bench/campaign.py`` is its command line; the CI test runs a few.

One robot per profile is launched once and flown through all its sequences, each ended on the ground
(:meth:`CampaignRobot.reset`): a launch costs tens of seconds, a reset a few.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from campaign_robot import CampaignRobot, Sequence
from campaign_shrink import shrink
from campaign_steps import PROFILES, GenConfig, Profile, Step, generate, show_steps


def repro_command(profile: str, steps: list[Step]) -> str:
    """The command line that flies ``steps`` again on a fresh robot (quoted for a POSIX shell)."""
    return f"python bench/campaign.py --robot {profile} --steps '{show_steps(steps)}'"


@dataclass
class Failure:
    """A sequence the monitor found breaches in (or the robot could not finish), with its reproduction."""

    profile: str
    index: int
    steps: list[Step]
    kinds: list[str]
    described: list[str]
    incident: str = ""
    shrunk: list[Step] | None = None
    shrink_runs: int = 0
    shrink_exhausted: bool = False

    def report(self) -> str:
        which = f"sequence {self.index}" if self.index >= 0 else f"given sequence {-self.index}"
        head = f"{which} on {self.profile}: " + (", ".join(self.kinds) or "no breach") + \
            (f"; incident: {self.incident}" if self.incident else "")
        lines = [head, f"  steps: {show_steps(self.steps)}", *("  " + d.replace("\n", "\n  ") for d in self.described)]
        if self.shrunk is not None:
            lines.append(f"  shrunk in {self.shrink_runs} runs{' (budget out)' if self.shrink_exhausted else ''} "
                         f"to {len(self.shrunk)} steps: {[str(s) for s in self.shrunk]}")
        lines.append("  reproduce: " + repro_command(self.profile, self.shrunk or self.steps))
        return "\n".join(lines)


@dataclass
class CampaignResult:
    seed: int
    sequences: list[dict[str, Any]] = field(default_factory=list)
    failures: list[Failure] = field(default_factory=list)
    sim_s: float = 0.0
    wall_s: float = 0.0
    launches: dict[str, float] = field(default_factory=dict)
    """Profile → wall seconds from launch to the monitor watching."""
    skipped: int = 0
    relaunches: int = 0
    """Robots launched again after one could not be brought back (an incident's consequence)."""
    """Sequences not run: the wall budget ran out."""

    @property
    def breaches(self) -> Counter[str]:
        return Counter(b for s in self.sequences for b in s["breach_kinds"])

    @property
    def incidents(self) -> int:
        return sum(1 for s in self.sequences if s["incident"])

    def summary(self) -> dict[str, Any]:
        by_kind = self.breaches
        flown = sum(s["wall_s"] for s in self.sequences)
        return {
            "campaign_sequences": len(self.sequences),
            "campaign_sim_hours": round(self.sim_s / 3600.0, 4),
            "campaign_breaches": sum(by_kind.values()),
            "campaign_breaches_by_kind": dict(sorted(by_kind.items())),
            "campaign_incidents": self.incidents,
            "campaign_seed": self.seed,
            "campaign_wall_s": round(self.wall_s, 1),
            "campaign_sim_speed": round(self.sim_s / flown, 2) if flown else None,
            "campaign_skipped": self.skipped,
            "campaign_relaunches": self.relaunches,
            "campaign_task_failures": sum(len(s["failed"]) for s in self.sequences),
        }


def describe(seq: Sequence) -> dict[str, Any]:
    return {"steps": show_steps(seq.steps), "sim_s": round(seq.sim_s, 1), "wall_s": round(seq.wall_s, 1),
            "outcomes": [f"{o.step}: {o.note} (t={o.sim_t:.1f})" for o in seq.outcomes],
            "breach_kinds": [b.kind for b in seq.breaches], "breaches": [b.describe() for b in seq.breaches],
            "incident": seq.incident, "watched": seq.watched, "failed": seq.failed}


def run_campaign(seed: int, n: int, profiles: list[Profile], workdir: Path, *, budget_s: float | None = None,
                 shrink_budget: int = 6, gen: GenConfig = GenConfig(), given: Iterable[list[Step]] = (),
                 log: Callable[[str], None] = print) -> CampaignResult:
    """The ``given`` sequences (regressions, a reproduction: indices -1, -2, ...) on ``profiles[0]``, then ``n``
    sequences of campaign ``seed``, sequence i on ``profiles[i % len(profiles)]``. Stops starting sequences once
    ``budget_s`` wall seconds have gone (the launches included), and shrinks a failing generated sequence only while
    the budget lasts."""
    t0 = time.monotonic()
    deadline = t0 + budget_s if budget_s is not None else None
    result = CampaignResult(seed)
    plan: dict[str, list[tuple[int, list[Step]]]] = {}
    for k, steps in enumerate(given):
        plan.setdefault(profiles[0].name, []).append((-k - 1, list(steps)))
    for i in range(n):
        p = profiles[i % len(profiles)]
        plan.setdefault(p.name, []).append((i, generate(seed, i, p, gen)))
    for name, todo in plan.items():
        profile = PROFILES[name]
        if deadline is not None and time.monotonic() > deadline:
            result.skipped += len(todo)
            continue
        robot = _launch(profile, workdir, log, deadline)
        try:
            result.launches[name] = round(robot.ready_s, 1)
            log(f"  up and watched in {robot.ready_s:.1f} s (launch {robot.launch_s:.1f} s)")
            for k, (index, steps) in enumerate(todo):
                if not _time_for_one(result, deadline):
                    result.skipped += len(todo) - k
                    log(f"wall budget of {budget_s:g} s spent: {len(todo) - k} sequences not run")
                    break
                seq = robot.run(Sequence(list(steps)))
                result.sim_s += seq.sim_s
                info = describe(seq) | {"index": index, "profile": name}
                result.sequences.append(info)
                kinds = sorted(set(info["breach_kinds"]))
                log(f"#{index} {name}: {len(steps)} steps, {seq.sim_s:.1f} sim s in {seq.wall_s:.1f} s: "
                    + (", ".join(kinds) if kinds else "no breach") + (f"; INCIDENT {seq.incident}" if seq.incident
                                                                        else "")
                    + "".join(f"\n    failed {f}" for f in seq.failed))
                if kinds or seq.incident:
                    failure = Failure(name, index, list(steps), kinds, info["breaches"], seq.incident)
                    if kinds and shrink_budget > 0 and index >= 0:
                        _shrink(robot, failure, shrink_budget, deadline, result, log)
                    result.failures.append(failure)
                if seq.incident and not robot.recovered():
                    robot.close()
                    result.relaunches += 1
                    robot = _launch(profile, workdir, log, deadline)
        finally:
            robot.close()
    result.wall_s = time.monotonic() - t0
    return result


LAUNCH_ATTEMPTS = 3


def _launch(profile: Profile, workdir: Path, log: Callable[[str], None], deadline: float | None) -> CampaignRobot:
    """The robot up and watched. A launch that fails to come up is tried again (on this loaded machine a process
    may miss its manifest's 15 s readiness window), not after the deadline; the last failure is raised."""
    for attempt in range(1, LAUNCH_ATTEMPTS + 1):
        if attempt > 1 and deadline is not None and time.monotonic() > deadline:
            raise AssertionError(f"{profile.manifest} did not come up before the wall budget ran out")
        log(f"launching {profile.manifest} in lockstep at --speed max (attempt {attempt}) ...")
        try:
            return CampaignRobot(profile, workdir / f"{profile.name}-{attempt}", log=log)
        except AssertionError as exc:
            if attempt == LAUNCH_ATTEMPTS:
                raise
            log(f"  did not come up: {str(exc).splitlines()[-1]}")
    raise AssertionError("unreachable")


def _time_for_one(result: CampaignResult, deadline: float | None) -> bool:
    """Whether a sequence as long on the wall as the mean so far still ends before the deadline."""
    if deadline is None:
        return True
    walls = [s["wall_s"] for s in result.sequences]
    return time.monotonic() + (sum(walls) / len(walls) if walls else 0.0) <= deadline


def _shrink(robot: CampaignRobot, failure: Failure, budget: int, deadline: float | None, result: CampaignResult,
            log: Callable[[str], None]) -> None:
    wanted = set(failure.kinds)

    def fails(candidate: list[Step]) -> bool:
        if not _time_for_one(result, deadline):
            return False
        seq = robot.run(Sequence(list(candidate)))
        got = {b.kind for b in seq.breaches}
        log(f"  shrink: {len(candidate)} steps -> {', '.join(sorted(got)) or 'no breach'}")
        return bool(got & wanted)

    out = shrink(failure.steps, fails, budget)
    failure.shrunk, failure.shrink_runs, failure.shrink_exhausted = out.steps, out.runs, out.exhausted
