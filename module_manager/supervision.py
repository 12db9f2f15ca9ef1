"""Supervision of one module process as a pure state machine with an injected clock.

The runtime feeds it events (spawned, alive/unreachable from liveliness, a matching RouteAck, a heartbeat, the
exit status from ``waitpid``) and the current time; ``tick(now)`` returns what to do next (spawn, kill). Nothing
here touches processes or the bus, so every policy is tested directly with a fake clock.

Rules (after systemd, OTP and dora, see docs/manifest.md):
- the exit status is the truth about death; a liveliness DELETE alone only means "unreachable" and is shown
  after a debounce, it never restarts anything;
- a module is ``up`` once it is alive *and* has acknowledged the routes the manager wants (a restarted module
  gets its routing back before it is counted as up);
- ``never``: no restart; ``on-failure``: restart after a non-zero exit, a signal, a start timeout or a watchdog
  kill; ``always``: restart after any exit that the manager did not ask for;
- the first failure inside the intensity window restarts at once (a crash or a SIGKILL costs no waiting);
  backoff applies from the second: ``backoff_s``, then doubling per further restart still inside the window,
  capped at ``backoff_max_s``; more than ``intensity`` restarts within
  ``period_s`` marks the module ``failed`` (it stays down and is reported) — counted also after a good start.
- exit status 78 (``bbcs.errors.EXIT_CONFIG``: the module's configuration is invalid) marks the module ``failed``
  at once, whatever the policy: a restart reads the same file and fails the same way.
"""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Literal

from bbcs import EXIT_CONFIG

RestartPolicy = Literal["never", "on-failure", "always"]


class Phase(enum.StrEnum):
    STARTING = "starting"
    UP = "up"
    RESTARTING = "restarting"
    """Down, waiting for the backoff delay before the next start."""
    STOPPING = "stopping"
    FAILED = "failed"
    STOPPED = "stopped"


@dataclass(frozen=True)
class Policy:
    """The supervision knobs of one module (manifest ``[supervision]`` merged with the module's overrides)."""

    restart: RestartPolicy = "on-failure"
    backoff_s: float = 0.5
    backoff_max_s: float = 8.0
    intensity: int = 5
    """At most this many restarts within ``period_s``; one more marks the module failed."""
    period_s: float = 10.0
    start_timeout_s: float = 20.0
    """A start that is not up (alive + routes acknowledged) by then is killed and counts as a failure."""
    watchdog_s: float = 0.0
    """Kill an up module whose heartbeat is older than this (0: no watchdog)."""
    unreachable_debounce_s: float = 1.0
    """A liveliness DELETE is reported as "unreachable" only if no PUT follows within this time."""
    standby: bool = False
    """Keep a warm standby process of the module while it runs, so a restart skips interpreter start and imports
    (module_manager/standby.py); costs one idle interpreter per module."""


@dataclass(frozen=True)
class Spawn:
    """Start the process now; ``restart_count`` goes into its context."""

    restart_count: int


@dataclass(frozen=True)
class Kill:
    """Stop the process: ``graceful`` is SIGTERM then SIGKILL after the grace period; otherwise SIGKILL now."""

    reason: str
    graceful: bool = True


Action = Spawn | Kill


@dataclass
class Supervisor:
    """State of one supervised module; all methods take ``now`` (monotonic seconds) from the caller."""

    policy: Policy
    needs_ack: bool = True
    """Whether the module must acknowledge its routes (it has routed inputs) before it counts as up."""
    needs_links: bool = False
    """Whether the module must have linked directly to every module already up before it counts as up (``[bus]
    links = "peers"``: a datum sent between two modules while their link forms can be lost, docs/bus.md)."""
    phase: Phase = Phase.STOPPED
    restarts: int = 0
    """Restarts done by the supervisor (not the ones asked for through the MRI)."""
    last_exit: int | None = None
    reason: str = ""
    alive: bool = False
    routes_ok: bool = False
    linked: bool = False
    unreachable: bool = False
    started_at: float = 0.0
    next_start_at: float | None = None
    _deleted_at: float | None = None
    _last_beat: float | None = None
    beat_clock: Callable[[], float] | None = None
    """What heartbeats are measured on (a lockstep simulation's time, docs/simulation.md); None: ``now``."""
    _kill_sent: bool = False
    _kill_counts_as_failure: bool = False
    _restart_requested: bool = False
    _window: deque[float] = field(default_factory=deque)
    _spawns: int = 0

    # ------------------------------------------------------------------ operator requests

    def start(self, now: float) -> None:
        """Start (first start, or an operator's start after stopped/failed): counters of the window reset."""
        if self.phase in (Phase.STARTING, Phase.UP, Phase.STOPPING):
            return
        self._window.clear()
        self.reason = ""
        self.phase = Phase.RESTARTING
        self.next_start_at = now

    def stop(self, now: float, reason: str = "stopped by request") -> list[Action]:
        """Stop and do not restart. Returns the kill to perform if a process runs."""
        self._restart_requested = False
        if self.phase in (Phase.STARTING, Phase.UP, Phase.STOPPING):
            self.phase = Phase.STOPPING
            self.reason = reason
            return self._kill(reason, graceful=True, failure=False)
        self.phase = Phase.STOPPED
        self.reason = reason
        self.next_start_at = None
        return []

    def restart(self, now: float) -> list[Action]:
        """Operator restart: stop the running process (if any) and start again at once, not counted as a failure."""
        if self.phase in (Phase.STARTING, Phase.UP, Phase.STOPPING):
            actions = self.stop(now, "restart requested")
            self._restart_requested = True
            return actions
        self.start(now)
        return []

    # ------------------------------------------------------------------ events from the runtime

    def blocked(self, reason: str) -> None:
        """Never started: a module it must start after failed. Shown as failed; an operator start still works."""
        self.phase = Phase.FAILED
        self.reason = reason
        self.next_start_at = None

    def spawned(self, now: float) -> None:
        self.phase = Phase.STARTING
        self.started_at = now
        self.alive = False
        self.routes_ok = not self.needs_ack
        self.linked = not self.needs_links
        self.unreachable = False
        self._deleted_at = None
        self._last_beat = None
        self._kill_sent = False
        self._kill_counts_as_failure = False
        self.next_start_at = None

    def spawn_failed(self, now: float, reason: str) -> None:
        """The process could not even be created (exec error): treated like a failing exit."""
        self.spawned(now)
        self.exited(now, 127, reason)

    def liveliness(self, now: float, present: bool) -> None:
        if present:
            self.alive = True
            self.unreachable = False
            self._deleted_at = None
        elif self.alive:
            self._deleted_at = now
        self._promote(now)

    def routes_acknowledged(self, now: float, matches: bool) -> None:
        """A RouteAck from the current run arrived; ``matches``: it shows the routes the manager wants."""
        if self.phase in (Phase.STARTING, Phase.UP):
            self.routes_ok = matches if self.phase is Phase.STARTING else (self.routes_ok or matches)
            self._promote(now)

    def routes_changed(self) -> None:
        """The manager asked for new routes: a module still starting must acknowledge them again."""
        if self.phase is Phase.STARTING and self.needs_ack:
            self.routes_ok = False

    @property
    def awaiting_links(self) -> bool:
        """Alive with its routes, starting, waiting only for its direct links (the manager looks at the kernel's
        socket tables: module_manager/direct_links.py)."""
        return self.phase is Phase.STARTING and self.alive and self.routes_ok and not self.linked

    def links_formed(self, now: float) -> None:
        """Every module already up has a direct link to this one (or the manager stopped waiting for them)."""
        if self.phase is Phase.STARTING:
            self.linked = True
            self._promote(now)

    def heartbeat(self, now: float) -> None:
        self._last_beat = now if self.beat_clock is None else self.beat_clock()

    def exited(self, now: float, code: int, detail: str = "") -> list[Action]:
        """``waitpid`` reported the exit: ``code`` >= 0 exit status, < 0 killed by that signal."""
        self.last_exit = code
        self.alive = False
        self.routes_ok = False
        self.unreachable = False
        self._deleted_at = None
        failure = code != 0 or self._kill_counts_as_failure
        how = detail or _describe_exit(code)
        if self.phase is Phase.STOPPING:
            if self._restart_requested:
                self._restart_requested = False
                self.phase = Phase.RESTARTING
                self.next_start_at = now
                self.reason = ""
            else:
                self.phase = Phase.STOPPED
            return []
        if code == EXIT_CONFIG:
            self.phase = Phase.FAILED
            self.reason = f"{how}: configuration error (fix the robot .conf, see the module's log); not restarted"
            return []
        wants = self.policy.restart == "always" or (self.policy.restart == "on-failure" and failure)
        if not wants:
            self.phase = Phase.FAILED if failure else Phase.STOPPED
            self.reason = f"{how}; restart policy {self.policy.restart}"
            return []
        horizon = now - self.policy.period_s
        while self._window and self._window[0] <= horizon:
            self._window.popleft()
        if len(self._window) >= self.policy.intensity:
            self.phase = Phase.FAILED
            self.reason = (f"{how}; restart intensity exceeded ({len(self._window)} restarts in "
                           f"{self.policy.period_s:g} s): not restarted again")
            return []
        delay = backoff_delay(self.policy, len(self._window))
        self._window.append(now)
        self.restarts += 1
        self.phase = Phase.RESTARTING
        self.next_start_at = now + delay
        self.reason = f"{how}; restart in {delay:g} s"
        return []

    # ------------------------------------------------------------------ time

    def tick(self, now: float) -> list[Action]:
        """What to do at ``now``: spawn after a backoff, kill a start that timed out or a silent module."""
        if self.phase is Phase.RESTARTING and self.next_start_at is not None and now >= self.next_start_at:
            self.next_start_at = None
            count = self._spawns
            self._spawns += 1
            return [Spawn(restart_count=count)]
        if self.phase is Phase.STARTING and now - self.started_at > self.policy.start_timeout_s:
            what = "alive" if not self.alive else "route acknowledgement" if not self.routes_ok else "direct links"
            return self._kill(f"start timeout: no {what} after {self.policy.start_timeout_s:g} s",
                              graceful=False, failure=True)
        if self.phase is Phase.UP:
            if (self._deleted_at is not None and not self.unreachable
                    and now - self._deleted_at >= self.policy.unreachable_debounce_s):
                self.unreachable = True
            wd = self.policy.watchdog_s
            beat_now = now if self.beat_clock is None else self.beat_clock()
            if wd > 0 and self._last_beat is not None and beat_now - self._last_beat > wd:
                return self._kill(f"watchdog: no heartbeat for {wd:g} s", graceful=False, failure=True)
        return []

    # ------------------------------------------------------------------ helpers

    @property
    def running(self) -> bool:
        """A process of this module exists (or is being started/stopped)."""
        return self.phase in (Phase.STARTING, Phase.UP, Phase.STOPPING)

    @property
    def state(self) -> str:
        """The MRI ``ModuleState`` of this module."""
        if self.phase is Phase.STOPPING:
            return "restarting" if self._restart_requested else "stopped"
        return str(self.phase)

    def _promote(self, now: float) -> None:
        if self.phase is Phase.STARTING and self.alive and self.routes_ok and self.linked:
            self.phase = Phase.UP
            self.reason = ""
            self._last_beat = now if self.beat_clock is None else self.beat_clock()

    def _kill(self, reason: str, *, graceful: bool, failure: bool) -> list[Action]:
        self._kill_counts_as_failure = self._kill_counts_as_failure or failure
        if self._kill_sent:
            return []
        self._kill_sent = True
        if failure:
            self.reason = reason
        return [Kill(reason=reason, graceful=graceful)]


def startable(waiting: set[str], after: dict[str, tuple[str, ...]], phases: dict[str, Phase]
              ) -> tuple[list[str], dict[str, str]]:
    """The launch's start order, one step: which of the ``waiting`` modules may start now (every module they
    start ``after`` is up; names that are not modules — processes — are ready before any module starts), and which
    can never start because one of those failed or was stopped (name → reason)."""
    start: list[str] = []
    blocked: dict[str, str] = {}
    for name in sorted(waiting):
        deps = [d for d in after.get(name, ()) if d in phases]
        dead = [d for d in deps if phases[d] in (Phase.FAILED, Phase.STOPPED) and d not in waiting]
        if dead:
            states = ", ".join(f"{d} {phases[d]}" for d in dead)
            blocked[name] = f"not started: it starts after {', '.join(dead)} ({states})"
        elif all(phases[d] is Phase.UP for d in deps):
            start.append(name)
    return start, blocked


def launch_gave_up(phases: Iterable[Phase]) -> bool:
    """A launch waiting for its robot to come up (``--once-up``) gives up when every module has settled and one
    of them is down for good. Every module up is no failure: the robot is up."""
    seen = list(phases)
    return (all(p in (Phase.UP, Phase.FAILED, Phase.STOPPED) for p in seen)
            and any(p is not Phase.UP for p in seen))


def backoff_delay(policy: Policy, recent_restarts: int) -> float:
    """Seconds to wait before a restart, given how many restarts are already in the intensity window: none for
    the first (a one-off crash is back at once), then ``backoff_s`` doubling per restart, capped."""
    if recent_restarts <= 0:
        return 0.0
    return min(policy.backoff_s * (2 ** (recent_restarts - 1)), policy.backoff_max_s)


def _describe_exit(code: int) -> str:
    if code < 0:
        return f"killed by signal {-code}"
    return f"exited with status {code}"
