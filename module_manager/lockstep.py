"""The Module Manager's part in a lockstep simulation (manifest ``[sim] lockstep = true``, docs/simulation.md).

Why the manager is a member: the robot state it publishes (telemetry, tasks, module health) is what the RAL
judges tasks on, so it must be published at the simulated times it is due, not whenever the manager's loop next
wakes on the wall. The manager answers each ask on Zenoh's thread, busy while modules are still starting (no step
is taken before the whole robot is up), while a module it restarts is coming back (``restarting``), while it serves
an MRI request, and while a robot state is due.
Its heartbeat watchdog measures simulated time (a module left behind by the steps stops beating in it).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Mapping

import zenoh

from bbcs.clock import SimClock
from bbcs.lockstep import MANAGER_MEMBER, Ask, Member, SimSettings, settings_env
from module_manager.manifest import Manifest
from module_manager.supervision import Phase

COMING_BACK = frozenset({Phase.RESTARTING, Phase.STARTING})
"""The phases of a module the manager is bringing back (its backoff, then its process starting)."""


def restarting(phases: Mapping[str, Phase], stopping_to_restart: Iterable[str] = ()) -> list[str]:
    """The modules whose restart holds the simulation: down and due back, or starting again, or stopped by a
    restart request. Their time to come back is the machine's (a backoff on the wall clock, an interpreter
    starting), not the flight's: held, it takes no simulated time, so the same mission gives the same flight at
    any load, and a RAL killed just before a loss of control is back to report it within the second, as on a
    robot, rather than some simulated seconds later at ``--speed max`` (the uQuad campaign, seed 7)."""
    return sorted({n for n, ph in phases.items() if ph in COMING_BACK} | set(stopping_to_restart))

SPEED_MAX = "max"


def parse_speed(text: str) -> float | str:
    """``--speed``: ``max`` (as fast as the modules allow) or a positive multiple of real time."""
    if text == SPEED_MAX:
        return SPEED_MAX
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"--speed takes 'max' or a positive number, not {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise ValueError(f"--speed must be a positive number, not {text!r}")
    return value


def settings_for(manifest: Manifest, connect: list[str], speed: float | str | None = None) -> SimSettings | None:
    """The lockstep settings of a launch (None: the manifest does not ask for lockstep); ``speed`` (``--speed``)
    overrides the manifest's ``[sim] speed``."""
    sim = manifest.raw.sim
    if not sim.lockstep:
        return None
    chosen = sim.speed if speed is None else speed
    return SimSettings(robot=manifest.robot, connect=list(connect),
                       speed=SPEED_MAX if chosen == SPEED_MAX else None if chosen is None else float(chosen),
                       step_s=sim.step_s, deadline_s=sim.deadline_s, fleet=list(sim.fleet))


class ManagerMember:
    """The manager's clock and answers. ``busy`` says what the manager still has to do ('' when done)."""

    def __init__(self, settings: SimSettings) -> None:
        self.settings = settings
        self.clock = SimClock()
        self.activity = 0
        """Bumped by the manager for every datum it takes in that the robot state reflects (telemetry)."""
        self._member: Member | None = None
        self._busy: Callable[[], str] = lambda: ""
        self._lock = threading.Lock()

    def env(self) -> dict[str, str]:
        """What every child of the launch is given (bbcs.lockstep.SIM_ENV)."""
        return settings_env(self.settings)

    def join(self, session: zenoh.Session, busy: Callable[[], str]) -> None:
        self._busy = busy
        self._member = Member(session, self.settings.robot, MANAGER_MEMBER, self._on_ask)

    def _on_ask(self, ask: Ask) -> None:
        with self._lock:
            self.clock.advance(ask.now)
            if self._member is not None:
                self._member.answer(ask, self.activity, self._busy())

    def close(self) -> None:
        with self._lock:
            if self._member is not None:
                self._member.close()
                self._member = None
