"""The lidar simulators as a member of a lockstep simulation's barrier (docs/simulation.md, docs/lidar_logger.md §8).

Started by a lockstep launch (``CROMAT_SIM`` in its environment) and flying with the DSP simulator's aircraft
(``--follow-udp``), the MTi-G/LD-MRS simulator process:

- keeps its world's clock on the **step**: ``StepClock`` stands at the time of the last step it was asked about
  (the stepper's ``Ask.now``), never past the newest truth datagram received, and moves only when the member has
  the truth of that step's last physics sub-step. Between two moves nothing it produces depends on the wall: the
  LD-MRS sends the scans that have ended (``LdmrsOptions.release_grid``), the MTi-G answers each ReqData with its
  next 20-ms sample once the clock has reached it (``MTiGDevice.sample_period``);
- holds a liveliness token as the member ``lidar_sim`` (``--lockstep-member``) and answers an ask only once its
  clock stands at the ask's time and its two servers have nothing left to write at it (``busy`` otherwise);
- reports in its answer the bytes each server wrote and read-and-handled on its device link
  (``bbcs.lockstep.wire_counts``, named as the lidar logger names them: ``mtig:<pty>``, ``ldmrs:<host>:<port>``),
  which the barrier pairs with the logger's own counts (``bbcs.lockstep.unpaired_wires``): a step is handled only
  once the logger has read every byte the simulators wrote, and they every byte it wrote.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from bbcs.lockstep import Ask, Member, wire_counts
from modules.lidar_logger.clock import ScaledClock
from modules.lidar_logger.ldmrs import ldmrs_link
from modules.lidar_logger.mtig import mtig_link

if TYPE_CHECKING:
    from modules.lidar_logger.sim.ldmrs_sim import LdmrsSimulator
    from modules.lidar_logger.sim.mtig_sim import MTiGSimulator

log = logging.getLogger(__name__)

SAMPLE_PERIOD_S = 0.02
"""The MTi-G's sample grid in lockstep: the logger's polling period (``LoggerSettings.pose_period_s``), 50 Hz."""
DEFAULT_MEMBER = "lidar_sim"
SETTLE_WAIT_S = 0.2
"""Wall seconds the member waits for its servers to finish what the new time made due before it answers busy
(the stepper then asks again)."""
TIME_EPS_S = 1e-9


class StepClock(ScaledClock):
    """The world's clock in lockstep: moved by ``advance`` to a step's time, once the truth has reached it.

    ``on_truth`` is the truth receiver's (``sim/follow.py``); ``subscribe`` gives a server a file descriptor
    that turns readable when the clock moves (a server's ``select`` wakes at once instead of polling)."""

    def __init__(self) -> None:
        super().__init__(1.0)
        self._cond = threading.Condition()
        self._now = 0.0
        self._newest: float | None = None
        self._wake: list[int] = []

    def on_truth(self, time_s: float, time_scale: float) -> None:
        with self._cond:
            if self._newest is None or time_s > self._newest:
                self._newest = time_s
                self._cond.notify_all()

    @property
    def newest_truth(self) -> float | None:
        with self._cond:
            return self._newest

    def has_truth(self, t: float) -> bool:
        """The truth of simulated time ``t`` has been received (time 0 needs none: nothing has moved)."""
        with self._cond:
            return t <= 0 or (self._newest is not None and self._newest >= t - TIME_EPS_S)

    def wait_truth(self, t: float, timeout: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: t <= 0 or (self._newest is not None
                                                          and self._newest >= t - TIME_EPS_S), timeout)

    def advance(self, t: float) -> bool:
        """Stand at ``t`` (never backwards); the subscribers are woken. False when it was already there."""
        with self._cond:
            if t <= self._now:
                return False
            self._now = t
            fds = list(self._wake)
        for fd in fds:
            try:
                os.write(fd, b"x")
            except OSError:  # a full pipe already wakes its reader
                pass
        return True

    def subscribe(self) -> int:
        r, w = os.pipe()
        os.set_blocking(r, False)
        os.set_blocking(w, False)
        with self._cond:
            self._wake.append(w)
        return r

    def now(self) -> float:
        return self._now

    def wall(self, seconds: float) -> float:
        """Unknown (simulated time moves when the barrier says): a bounded poll; a move wakes the servers."""
        return 0.0 if seconds <= 0 else 0.05


class SimMember:
    """The process's part in the barrier: takes the newest ask, waits for its truth, moves the clock, answers.

    ``state(now)`` gives (busy, counts) of both servers at clock time ``now``, read consistently."""

    def __init__(self, session, robot: str, name: str, clock: StepClock,
                 state: Callable[[float], tuple[str, dict[str, int]]]) -> None:
        self.clock = clock
        self.state = state
        self.answers = 0
        self._cond = threading.Condition()
        self._ask: Ask | None = None
        self._stop = threading.Event()
        self._member = Member(session, robot, name, self._on_ask)
        self._thread = threading.Thread(target=self._run, name="lidar-sim-lockstep", daemon=True)
        self._thread.start()

    def _on_ask(self, ask: Ask) -> None:
        with self._cond:
            if self._ask is None or (ask.step, ask.round) > (self._ask.step, self._ask.round):
                self._ask = ask
            self._cond.notify_all()

    def _take(self) -> Ask | None:
        with self._cond:
            self._cond.wait_for(lambda: self._ask is not None or self._stop.is_set(), 0.2)
            ask, self._ask = self._ask, None
            return ask

    def _newer(self) -> bool:
        with self._cond:
            return self._ask is not None

    def _run(self) -> None:
        warned_at = time.monotonic()
        while not self._stop.is_set():
            ask = self._take()
            if ask is None:
                continue
            t = ask.now.t
            while not self.clock.wait_truth(t, 0.05):  # the DSP simulator sent it before it asked: it is on its way
                if self._stop.is_set() or self._newer():
                    break  # a newer ask (this one was given up on: the stepper went on without us)
                if time.monotonic() - warned_at > 10.0:
                    warned_at = time.monotonic()
                    log.warning("lockstep: step %d (t=%.3f s) still without its truth (newest %s)", ask.step, t,
                                self.clock.newest_truth)
            else:
                self.clock.advance(t)
                self._answer(ask)

    def _answer(self, ask: Ask) -> None:
        t = self.clock.now()
        end = time.monotonic() + SETTLE_WAIT_S
        busy, counts = self.state(t)
        while busy and time.monotonic() < end and not self._stop.is_set() and not self._newer():
            time.sleep(0.001)
            busy, counts = self.state(t)
        self.answers += 1
        self._member.answer(ask, activity=sum(counts.values()), busy=busy, counts=counts)

    def close(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        self._thread.join(timeout=2.0)
        self._member.close()


def server_state(imu: MTiGSimulator, lidar: LdmrsSimulator) -> Callable[[float], tuple[str, dict[str, int]]]:
    """(busy, counts) of both servers at a clock time, for the member's answer: what is still due, and each server's
    end of its device link (``wire_counts``, named as the logger names them)."""
    mtig, ldmrs = mtig_link(imu.port), ldmrs_link(lidar.host, lidar.port)

    def state(now: float) -> tuple[str, dict[str, int]]:
        busy = [b for b in (imu.lockstep_busy(now), lidar.lockstep_busy(now)) if b]
        counts = {**wire_counts(mtig, imu.bytes_tx, imu.bytes_rx), **wire_counts(ldmrs, lidar.bytes_tx,
                                                                                  lidar.bytes_rx)}
        return "; ".join(busy), counts
    return state
