"""Every stamp the monitor compares, on the robot's one clock (bbcs/clock.py).

Why: the monitor compares stamps written by different processes (the task book, the DSP process's ``sent``
records, the GRI, the simulator's truth). On a robot they are all wall-clock stamps. In a lockstep simulation the
robot's clock is simulated time (``epoch + t``); the RAL, the telemetry module, the Module Manager (its task book
and errors) and the DSP process (its ``sent`` records) stamp on it, a process built otherwise on the wall clock, and
the simulator's truth carries its own ``time_s`` (seconds since the simulation began). Comparing a wall stamp
with a simulated one looks up the aircraft at another moment of the flight (at ``--speed max`` the simulation runs
seconds or minutes ahead of the wall, and starts behind it).

:class:`RobotTime` turns each of them into robot time:

- the truth: ``epoch + time_s`` (in lockstep the DSP simulator is the stepper: its ``time_s`` *is* ``t``);
- a stamp on the wall clock: the robot time that was in force at that wall instant. Simulated time stands still
  between two steps, so it is a step function of the wall: the monitor notes the wall time at which each step's
  ``SimTime`` reached it (``note_step``) and looks the stamp up there;
- a stamp already on the robot's clock: unchanged.

Which clock a process stamps on is learned from its fresh stamps (a record stamped as it is published): the one
of the two clocks it is nearer to, decided once the two clocks are more than ``DECIDE_S`` apart (when they are
closer, either reading gives nearly the same robot time). A process moved to the robot's clock later is then
followed without a change here.
"""

from __future__ import annotations

import bisect
import time
from collections.abc import Callable, Mapping

from bbcs.clock import SimTime

DECIDE_S = 5.0
"""Wall and robot clocks this far apart tell which one a fresh stamp is on."""
MAX_STEPS = 200_000
"""Steps remembered for the wall → robot look-up (11 simulated hours at 0.2 s a step)."""


STAMPED_ON_WALL: dict[str, bool] = {"dsp": False, "manager": False, "ral": False, "telemetry": False}
"""Which clock each source stamps on in lockstep (True: the wall), as the processes are built: all on the robot's
clock (the DSP process's ``sent`` records since 2026-11-28: mapped from the wall by the step in force, a command
could land a frame before the task the manager had started, exactly, at that step). Known from the start, so a
stamp is never guessed while the two clocks are still close (the simulation starts near the wall): a task started
then and judged later was once put on the wrong clock. Still learned from fresh stamps."""


class RobotTime:
    """Stamps in, robot time out. ``robot_now``: the robot's clock (the module's ``bbcs_clock.time``); ``wall``:
    the host's. Without lockstep (``simulated`` False) every stamp is already on the one clock, the wall."""

    def __init__(self, robot_now: Callable[[], float], *, simulated: bool,
                 wall: Callable[[], float] = time.time, known: Mapping[str, bool] | None = None) -> None:
        self.robot_now = robot_now
        self.simulated = simulated
        self.wall = wall
        self.epoch: float | None = None
        self._walls: list[float] = []
        self._robot: list[float] = []
        self.on_wall: dict[str, bool] = dict(known or {})
        """Source → whether it stamps on the wall clock (``known`` at the start, learned from its fresh stamps)."""

    def note_step(self, now: SimTime, wall: float | None = None) -> None:
        """The stepper's ``SimTime`` has just arrived (any thread): from this wall instant the robot's clock reads
        ``now``."""
        w = self.wall() if wall is None else wall
        r = now.epoch + now.t
        self.epoch = now.epoch
        if self._robot and (r <= self._robot[-1] or w < self._walls[-1]):
            return  # a repeated or older publication: the clock never goes back
        self._walls.append(w)
        self._robot.append(r)
        if len(self._walls) > MAX_STEPS:
            del self._walls[: MAX_STEPS // 10], self._robot[: MAX_STEPS // 10]

    def from_wall(self, w: float) -> float:
        """The robot time in force at wall instant ``w``. Before the first step noted: that step's time less the
        wall seconds before it (the simulation's speed then is unknown; nothing stepped before the robot was up)."""
        if not self.simulated:
            return w
        if not self._walls:
            return self.robot_now() - (self.wall() - w)
        i = bisect.bisect_right(self._walls, w) - 1
        if i < 0:
            return self._robot[0] - (self._walls[0] - w)
        return self._robot[i]

    def truth(self, time_s: float) -> float | None:
        """The simulator's ``time_s`` on the robot's clock; None while the epoch is not known yet (lockstep), or
        without lockstep, where the truth's time is its own (the caller stamps it on arrival)."""
        if not self.simulated or self.epoch is None:
            return None
        return self.epoch + time_s

    def learn(self, source: str, fresh: float) -> None:
        """``fresh``: a stamp ``source`` wrote just now (a state it published). Decides its clock when the two
        clocks are far enough apart to tell."""
        if not self.simulated:
            return
        w, r = self.wall(), self.robot_now()
        if abs(w - r) >= DECIDE_S:
            self.on_wall[source] = abs(fresh - w) < abs(fresh - r)

    def stamp(self, source: str, s: float) -> float:
        """A stamp of ``source`` on the robot's clock. A source not yet decided is taken to be on the clock its
        stamp is nearer to now."""
        if not self.simulated:
            return s
        wall = self.on_wall.get(source)
        if wall is None:
            wall = abs(s - self.wall()) < abs(s - self.robot_now())
        return self.from_wall(s) if wall else s


def truth_behind(read_s: float, step_s: float, period_s: float = 0.0) -> bool:
    """Lockstep: whether the truth read so far (up to simulated ``read_s``) may still miss a sample of the step that
    ends at ``step_s``. A simulator that sends its truth at every step's end (the DSP simulator, ``period_s`` 0) is
    behind until it has read ``step_s`` itself. One that samples its truth every ``period_s`` at its own instants
    (the uQuad simulator's 0.05 s at its 0.01 s frames) may have sent the step's last sample up to a period before
    its end: it is behind only while what it read is more than a period old (else a step whose end no sample fell on
    waited out the 2 wall seconds of silence: the uQuad campaign flew at 0.1x once its sums of 0.05 s and 0.2 s
    drifted an ulp apart)."""
    return read_s < step_s - period_s - 1e-6
