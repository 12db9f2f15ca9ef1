"""The flight-safety monitor's contract: the invariants it judges, a breach with its evidence, and its status.

The monitor (``modules/safety_monitor``, docs/simulation.md "Flight-safety monitor") watches the DSP's ``sent``
stream, the DSP telemetry, the Module Manager's task book, the GRI and, in simulation, the simulator's truth, and
publishes every breach of the invariants below:

| slot (``cromat/<robot>/safety_monitor/<slot>``) | kind | struct |
| --- | --- | --- |
| ``breach`` | stream, safe | :class:`Breach`: one per breach, with its evidence |
| ``status`` | state, safe | :class:`MonitorStatus`: what it has watched so far, breaches by invariant |
| ``error``  | state, safe | :class:`bbcs.contracts.errors.ErrorReport`: a :class:`BreachCode` per breach |
"""

from __future__ import annotations

from enum import IntEnum

import msgspec

MODULE = "safety_monitor"
BREACH_SLOT = "breach"
STATUS_SLOT = "status"


class Invariant(IntEnum):
    """The rules of issue 31 the monitor judges (their numbers there)."""

    COMMAND_TRACED = 1
    """Every DSP command has an accepted task, the failsafe or the start-up sequence behind it."""
    TASK_VERDICT = 2
    """A task completes only at its goal, and is never failed while the aircraft makes progress."""
    GRI_TRUTH = 3
    """The GRI agrees with the truth (position, airborne, health); a loss of control is reported within 1 s."""
    ABORT_LATENCY = 4
    """An abort reaches the DSP within 100 ms of the request."""
    ENVELOPE = 5
    """Never outside the geofence; never below MIN_CLEARANCE while airborne, except taking off or landing."""


class Severity(IntEnum):
    WARNING = 1
    """Wrong but harmless on its own (e.g. a stop command nothing asked for)."""
    ERROR = 2
    """The robot or its ground station is wrong about the flight (a verdict, a late abort, the GRI off the truth)."""
    CRITICAL = 3
    """The aircraft moves unasked, leaves its envelope, or loses control unreported."""


class BreachCode(IntEnum):
    """The code the monitor puts on its ERROR slot for each breach (one per invariant, docs/error_codes.md)."""

    UNTRACED_COMMAND = 901
    WRONG_VERDICT = 902
    GRI_DISAGREES = 903
    ABORT_LATE = 904
    ENVELOPE_LEFT = 905


CODE_OF: dict[Invariant, BreachCode] = dict(zip(Invariant, BreachCode, strict=True))


class Breach(msgspec.Struct, frozen=True, kw_only=True):
    """One breach of one invariant, with what the monitor saw (each line of ``evidence`` one observation)."""

    robot: str
    invariant: Invariant
    kind: str
    """What exactly: ``untraced_command``, ``completed_away_from_goal``, ``failed_while_progressing``,
    ``gri_position``, ``gri_airborne``, ``loss_of_control_unreported``, ``abort_late``, ``abort_missing``,
    ``outside_geofence``, ``below_clearance``."""
    severity: Severity
    stamp: float
    """When it happened (the robot's clock, seconds): the command's, the verdict's, the first sample out."""
    summary: str
    evidence: list[str] = msgspec.field(default_factory=list)
    task_id: int = 0
    """The task concerned, 0 when none."""

    def describe(self) -> str:
        """Multi-line text for a test failure or a log: the summary, then each piece of evidence."""
        head = f"[{self.severity.name} invariant {int(self.invariant)} {self.kind}] {self.summary}"
        return "\n".join([head, *(f"    {line}" for line in self.evidence)])


class MonitorStatus(msgspec.Struct, frozen=True, kw_only=True):
    """What the monitor has watched: a monitor that saw nothing cannot vouch for a flight."""

    robot: str
    stamp: float
    commands: int = 0
    """DSP commands seen on the ``sent`` stream."""
    commands_judged: int = 0
    telemetry: int = 0
    truth: int = 0
    """Simulator truth samples (0 on a real robot)."""
    tasks: int = 0
    """Tasks seen in the task book."""
    verdicts: int = 0
    """Ended tasks whose verdict was judged."""
    gri_states: int = 0
    gri_compared: int = 0
    """GRI states whose telemetry was compared with the truth at its stamp."""
    books: int = 0
    """Task books (Module Manager robot states) seen."""
    breaches: dict[str, int] = msgspec.field(default_factory=dict)
    """Breach kind → how many."""
