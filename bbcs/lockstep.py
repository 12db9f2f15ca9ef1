"""Lockstep simulation: the simulator advances only once every module has handled what the last step produced.

The parts (docs/simulation.md, "Lockstep"):

- **Settings** reach every process of a lockstep launch in the ``CROMAT_SIM`` environment variable (JSON of
  :class:`SimSettings`), set by the Module Manager from the manifest's ``[sim]`` table and ``cromat launch
  --speed``. Without it a process runs on the wall clock and takes no part: real hardware is untouched.
- **The stepper** (a simulator; :class:`Stepper`) publishes simulated time on ``cromat/<robot>/@clock`` and,
  after each step, *asks* the members on ``@lockstep/ask``; each member answers on ``@lockstep/done/<name>``.
- **A member** (every bbcs Module, the manager; :class:`Member`) holds a liveliness token under
  ``@lockstep/member/<name>`` while it takes part. A Module answers from its event loop only when the loop is idle
  (queue and channel empty, due timers run, no handler running), with a count of what it has handled
  (``activity``), what its own threads still hold (``busy``, e.g. a DSP batch not yet sent) and device counters
  (``counts``, e.g. bytes on the DSP line).
- **The barrier** (:class:`Barrier`, pure, with an injected wall time): a step is handled once every member has
  answered a round not busy, the stepper's own check passes (the DSP line carried every byte both ways), every
  device link between two members carried every byte both ways (``unpaired_wires``), and two
  consecutive rounds show the same activity everywhere (nothing was still travelling between members). A member
  that does not answer within ``deadline_s`` wall seconds is left behind (named in the log) until it answers
  again: its heartbeat then stops in simulated time, and the manager's watchdog, on simulated time, restarts it.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Literal

import msgspec
import zenoh

from bbcs import keys
from bbcs.clock import SimTime

log = logging.getLogger(__name__)

SIM_ENV = "CROMAT_SIM"
MANAGER_MEMBER = "manager"
"""The manager's member name (no module may be called so: the manager's own slots live under it). Not
``@manager``: a key chunk starting with ``@`` is matched by no wildcard."""
FOLLOWER_MEMBER = "sim"
"""A fleet follower simulator's member name (``Follower``): the fleet's stepper requires it, as a manager (no module
or process of a fleet robot may be called so, module_manager/manifest.py)."""
DEFAULT_STEP_S = 0.2
DEFAULT_DEADLINE_S = 20.0
SLOW_STEP_S = 5.0
"""Wall seconds after which a step not yet handled is logged once with what holds it (long before the deadline
leaves anyone behind: a stalled simulation names its cause while it is stalled)."""
RETRY_FIRST_S = 0.002
RETRY_MAX_S = 0.05
"""A round that finds a member busy is asked again after a pause growing from RETRY_FIRST_S to RETRY_MAX_S:
asking at once would wake every member in a tight loop while one of them finishes its work."""


class SimSettings(msgspec.Struct, frozen=True, kw_only=True):
    """How a lockstep simulation runs (manifest ``[sim]``, ``cromat launch --speed``)."""

    robot: str
    connect: list[str] = msgspec.field(default_factory=list)
    """The robot router's endpoints, for the simulators (modules get theirs from their context)."""
    speed: float | Literal["max"] | None = None
    """Simulated seconds per wall second at most; "max": as fast as every member allows; None: the simulator's
    own ``--time-scale``."""
    step_s: float = DEFAULT_STEP_S
    """Simulated seconds between two barriers (the simulators sub-step their physics inside it)."""
    deadline_s: float = DEFAULT_DEADLINE_S
    """Wall seconds a step waits for a member before leaving it behind."""
    fleet: list[str] = msgspec.field(default_factory=list)
    """Robots that step together on one barrier (manifest ``[sim] fleet``; this robot among them): the first
    one's simulator is the fleet's stepper, the others' simulators follow its steps (``Follower``). Empty: this
    robot alone."""

    @property
    def leads(self) -> bool:
        """This robot's simulator is the stepper (alone, or the first robot of its fleet)."""
        return not self.fleet or self.fleet[0] == self.robot


TIME_QUERY_S = 2.0
"""Wall seconds a starting module waits for the stepper's answer to "what time is it"."""


def settings_from_env(environ: Mapping[str, str] | None = None) -> SimSettings | None:
    """The lockstep settings this process was started with, or None (wall clock, no lockstep)."""
    text = (os.environ if environ is None else environ).get(SIM_ENV)
    if not text:
        return None
    try:
        return msgspec.json.decode(text, type=SimSettings)
    except msgspec.MsgspecError as exc:
        raise ValueError(f"{SIM_ENV} is not valid lockstep settings: {exc}") from None


def settings_env(settings: SimSettings) -> dict[str, str]:
    return {SIM_ENV: msgspec.json.encode(settings).decode()}


# --- keys ------------------------------------------------------------------------------------------------------


def _robot_key(robot: str, *parts: str) -> str:
    keys.validate_name(robot, "robot name")
    return "/".join((keys.ROOT, robot, *parts))


def clock_key(robot: str) -> str:
    """Where the stepper publishes ``SimTime`` (any tool may read the simulation's time here)."""
    return _robot_key(robot, "@clock")


def ask_key(robot: str) -> str:
    return _robot_key(robot, "@lockstep", "ask")


def done_key(robot: str, member: str) -> str:
    return _robot_key(robot, "@lockstep", "done", member)


def member_key(robot: str, member: str) -> str:
    return _robot_key(robot, "@lockstep", "member", member)


def member_of(key: str) -> str:
    return key.rsplit("/", 1)[-1]


# --- messages --------------------------------------------------------------------------------------------------


class Ask(msgspec.Struct, frozen=True, kw_only=True):
    """The stepper's question after a step: have you handled everything? (``now``: the time after the step)."""

    step: int
    round: int
    now: SimTime


class Done(msgspec.Struct, frozen=True, kw_only=True):
    """A member's answer to one round, given when it had nothing left to do."""

    member: str
    step: int
    round: int
    activity: int
    """Data handled so far (any count that grows with every datum, timer and call the member handles)."""
    busy: str = ""
    """Why the member is not finished although its loop is idle (its own threads' work); '' when finished."""
    counts: dict[str, int] = msgspec.field(default_factory=dict)
    """Device counters the stepper compares with its own (e.g. bytes on the DSP line), and the ends of device links
    between two members, which the barrier pairs (``wire_counts``, ``unpaired_wires``)."""


WIRE_PREFIX = "wire/"
"""Counts named ``wire/<link>/tx`` and ``wire/<link>/rx`` are a device link's two ends (see ``unpaired_wires``)."""


def wire_counts(link: str, tx: int, rx: int) -> dict[str, int]:
    """One end of a device link, as a member reports it in ``Done.counts``: the bytes it wrote on the link and
    the bytes it read *and handled* from it (``link`` names the link the same way at both ends)."""
    return {f"{WIRE_PREFIX}{link}/tx": tx, f"{WIRE_PREFIX}{link}/rx": rx}


def wire_end(counts: Mapping[str, int], link: str) -> tuple[int, int] | None:
    """One member's end of ``link`` from its ``Done.counts`` (``wire_counts``): (written, read), or None."""
    tx, rx = counts.get(f"{WIRE_PREFIX}{link}/tx"), counts.get(f"{WIRE_PREFIX}{link}/rx")
    return None if tx is None or rx is None else (tx, rx)


def unpaired_wires(answers: Mapping[str, Done]) -> str:
    """The barrier's rule for device links between two members ('' when met): for every link reported by two
    members (``wire_counts``), what each end wrote the other has read, both ways. A link reported by one member
    alone (its other end is not a member, or was left behind) is not judged; nor one reported by more than two
    (not a point-to-point link). E.g. the lidar simulators (``modules/lidar_logger/sim``) and the lidar logger on
    the MTi-G's pty and the LD-MRS's TCP connection: a scan written but not yet read keeps the step open."""
    ends: dict[str, dict[str, tuple[int, int]]] = {}
    for member, done in answers.items():
        for key, value in done.counts.items():
            if not key.startswith(WIRE_PREFIX):
                continue
            link, _, direction = key[len(WIRE_PREFIX):].rpartition("/")
            if not link or direction not in ("tx", "rx"):
                continue
            tx, rx = ends.setdefault(link, {}).get(member, (0, 0))
            ends[link][member] = (value, rx) if direction == "tx" else (tx, value)
    unmet = []
    for link, by_member in sorted(ends.items()):
        if len(by_member) != 2:
            continue
        (a, (a_tx, a_rx)), (b, (b_tx, b_rx)) = sorted(by_member.items())
        if a_tx != b_rx or b_tx != a_rx:
            unmet.append(f"link {link}: {a} wrote {a_tx} B ({b} read {b_rx}), {b} wrote {b_tx} B ({a} read {a_rx})")
    return "; ".join(unmet)


_encode = msgspec.msgpack.Encoder().encode
_decode_ask = msgspec.msgpack.Decoder(Ask).decode
_decode_done = msgspec.msgpack.Decoder(Done).decode
_decode_time = msgspec.msgpack.Decoder(SimTime).decode


def current_time(session: zenoh.Session, robot: str, timeout_s: float = TIME_QUERY_S) -> SimTime | None:
    """The simulation's time from the robot's stepper, or None when no stepper answers (the simulation has not
    begun: its time is 0). A module restarted in the middle of a simulation reads it before it takes any input:
    until its first ask its clock would otherwise say 0 while the robot is thousands of seconds in, and whatever
    it stamped or timed with it meanwhile (a task's start, seen again from the manager's task book by a
    restarted RAL) would be that far in the past."""
    for reply in session.get(clock_key(robot), timeout=timeout_s):
        if reply.ok is not None:
            try:
                return decode_time(reply.ok.payload.to_bytes())
            except msgspec.MsgspecError:
                continue
    return None


def decode_time(payload: bytes) -> SimTime:
    return _decode_time(payload)


# --- the member's side -----------------------------------------------------------------------------------------


class Member:
    """One process's part in the barrier: its token, the asks it receives, the answers it gives.

    ``on_ask`` runs on Zenoh's thread: it hands the ask to whoever answers (a Module's loop), which calls
    ``answer`` once it has handled everything that came before the ask."""

    def __init__(self, session: zenoh.Session, robot: str, name: str, on_ask: Callable[[Ask], None]) -> None:
        self.robot = robot
        self.name = name
        self._on_ask = on_ask
        self._pub = session.declare_publisher(done_key(robot, name), congestion_control=zenoh.CongestionControl.BLOCK,
                                              reliability=zenoh.Reliability.RELIABLE)
        self._sub = session.declare_subscriber(ask_key(robot), self._received)
        self._token = session.liveliness().declare_token(member_key(robot, name))
        self.answered = 0

    def _received(self, sample: zenoh.Sample) -> None:
        try:
            ask = _decode_ask(sample.payload.to_bytes())
        except msgspec.MsgspecError as exc:
            log.warning("lockstep: unreadable ask dropped: %s", exc)
            return
        self._on_ask(ask)

    def answer(self, ask: Ask, activity: int, busy: str = "", counts: dict[str, int] | None = None) -> None:
        self.answered += 1
        self._pub.put(_encode(Done(member=self.name, step=ask.step, round=ask.round, activity=activity, busy=busy,
                                   counts=counts or {})))

    def close(self) -> None:
        for entity in (self._token, self._sub, self._pub):
            try:
                entity.undeclare()
            except Exception as exc:  # the session may already be closing
                log.debug("lockstep member close: %s", exc)


# --- the barrier (pure) ----------------------------------------------------------------------------------------


class Verdict(Enum):
    WAIT = "wait"
    ASK = "ask"
    STEP = "step"


@dataclass
class Decision:
    verdict: Verdict
    round: int = 0
    delay: float = 0.0
    """ASK: wall seconds to wait before asking (a member was busy)."""
    left_behind: list[str] = field(default_factory=list)
    why: str = ""


@dataclass
class Barrier:
    """When the step's effects are handled: the rules of the module docstring, on an injected wall time.

    ``check`` is the stepper's own condition on the answers ('' when met): e.g. the DSP simulator's byte counts
    against the DSP module's. ``required`` members are waited for however long it takes (the manager: it says
    busy until every module is up)."""

    deadline_s: float = DEFAULT_DEADLINE_S
    required: frozenset[str] = frozenset()
    check: Callable[[Mapping[str, Done]], str] | None = None
    release_on_leave: bool = False
    """A fleet: a required member that leaves (its robot killed or stopped) is no longer required, so the other
    robots fly on; it is waited for as any member if it comes back. Alone, a robot's required manager is the robot."""
    reask: bool = False
    """A required member joined after the current round was asked (it never got the ask): ask the round again."""
    step: int = -1
    round: int = 0
    started: float = 0.0
    members: set[str] = field(default_factory=set)
    asked: set[str] = field(default_factory=set)
    """Members present when the current round was asked: one that joins later is waited for from the next round
    (it never got this round's ask)."""
    behind: dict[str, int] = field(default_factory=dict)
    """Members left behind → the step they were left at."""
    answers: dict[str, Done] = field(default_factory=dict)
    previous: dict[str, tuple[int, tuple[tuple[str, int], ...]]] | None = None
    warned_at: float = 0.0
    begun: float = 0.0
    """Wall time the step began (``started`` moves while a required member holds the step)."""
    slow_logged: bool = False
    busy_rounds: int = 0
    last: dict[str, tuple[int, tuple[tuple[str, int], ...]]] = field(default_factory=dict)
    changed: list[str] = field(default_factory=list)
    """Members whose activity or counts changed between the last two rounds (what keeps a step unsettled)."""

    def begin(self, step: int, now: float) -> None:
        self.step, self.round, self.started, self.warned_at, self.begun = step, 0, now, now, now
        self.slow_logged = False
        self.reask = False
        self.asked = set(self.members)
        self.busy_rounds = 0
        self.last = {}
        self.answers.clear()
        self.previous = None

    def joined(self, member: str) -> None:
        self.members.add(member)
        if member in self.required and member not in self.asked and self.step >= 0:
            self.asked.add(member)
            self.reask = True

    def left(self, member: str) -> None:
        if self.release_on_leave and member in self.required:
            self.required = self.required - {member}
            log.warning("lockstep: %s left; the fleet steps on without it", member)
        self.members.discard(member)
        self.asked.discard(member)
        self.behind.pop(member, None)
        self.answers.pop(member, None)

    def answer(self, done: Done) -> None:
        if done.member in self.behind and done.step >= self.behind[done.member]:
            del self.behind[done.member]  # it caught up: waited for again
            log.warning("lockstep: %s answers again (step %d)", done.member, done.step)
        if done.step == self.step and done.round == self.round:
            self.answers[done.member] = done

    def expected(self) -> set[str]:
        return ((self.asked & self.members) | set(self.required)) - set(self.behind)

    def decide(self, now: float) -> Decision:
        decision = self._decide(now)
        if decision.verdict is not Verdict.STEP and not self.slow_logged and now - self.begun > SLOW_STEP_S:
            self.slow_logged = True
            log.warning("lockstep: step %d not handled after %.1f s of wall: %s", self.step, now - self.begun,
                        decision.why or "?")
        return decision

    def _decide(self, now: float) -> Decision:
        expected = self.expected()
        absent = set(self.required) - self.members
        if absent:
            return self._wait(now, f"required member(s) {sorted(absent)} not present")
        answers = {m: d for m, d in self.answers.items() if m in expected}
        missing = sorted(expected - set(answers))
        late = now - self.started > self.deadline_s
        if missing:
            if late and not set(missing) & set(self.required):
                return self._leave(missing, f"no answer within {self.deadline_s:g} s")
            return self._wait(now, f"waiting for {missing}")
        busy = {m: d.busy for m, d in answers.items() if d.busy}
        if set(busy) & set(self.required):
            self.started = now  # nobody is late while a required member (the manager starting the robot) holds the step
        unmet = "; ".join(w for w in (self.check(answers) if self.check is not None else "",
                                      unpaired_wires(answers)) if w)
        vector = {m: (d.activity, tuple(sorted(d.counts.items()))) for m, d in answers.items()}
        if not busy and not unmet and vector == self.previous:
            return Decision(Verdict.STEP)
        self.changed = sorted(m for m in vector if self.last.get(m) != vector[m])
        self.last = vector
        if late and not set(busy) & set(self.required):
            why = "; ".join([*(f"{m}: {w}" for m, w in sorted(busy.items())), *([unmet] if unmet else [])])
            return self._leave(sorted(busy), f"not settled after {self.deadline_s:g} s "
                                             f"({why or 'still active: ' + ', '.join(self.changed)})")
        self.previous = None if busy or unmet else vector
        self.busy_rounds = self.busy_rounds + 1 if busy or unmet else 0
        delay = min(RETRY_FIRST_S * 2 ** (self.busy_rounds - 1), RETRY_MAX_S) if self.busy_rounds else 0.0
        self.round += 1
        self.answers.clear()
        self.asked = set(self.members)
        return Decision(Verdict.ASK, self.round, delay,
                        why="; ".join([*(f"{m}: {w}" for m, w in busy.items()), *([unmet] if unmet else [])])
                        or "still active: " + ", ".join(self.changed))

    def _wait(self, now: float, why: str) -> Decision:
        if now - self.warned_at > self.deadline_s:
            self.warned_at = now
            log.warning("lockstep: step %d still %s", self.step, why)
        return Decision(Verdict.WAIT, self.round, why=why)

    def _leave(self, members: list[str], why: str) -> Decision:
        for m in members:
            self.behind[m] = self.step
        if members:
            log.warning("lockstep: step %d goes on without %s (%s)", self.step, members, why)
        else:
            log.warning("lockstep: step %d goes on (%s)", self.step, why)
        return Decision(Verdict.STEP, left_behind=members, why=why)


# --- the stepper's side ----------------------------------------------------------------------------------------


def _own_answers(check: Callable[[Mapping[str, Done]], str],
                 robot: str) -> Callable[[Mapping[str, Done]], str]:
    """A stepper's check on its own robot's answers only (another robot's DSP module counts another line)."""
    prefix = f"{robot}/"

    def own(answers: Mapping[str, Done]) -> str:
        return check({m[len(prefix):]: d for m, d in answers.items() if m.startswith(prefix)})

    return own


class Stepper:
    """A simulator's end of the barrier, on its own Zenoh session; made for a ``select`` loop.

    ``begin(t)`` publishes the new time and the first round; ``poll()`` answers True once the step is handled
    (asking further rounds as needed). Answers and membership changes arrive on Zenoh's threads and are handed
    over through a pipe: ``wake_fd`` turns readable (call ``drain_wake()`` then ``poll()``).

    ``fleet``: the robots stepping on this barrier (``SimSettings.fleet``, this robot first). Each robot's members
    are asked on its own keys and named ``<robot>/<member>`` here; every robot's manager and every other robot's
    simulator (``Follower``) are required, until they leave. ``check`` sees this robot's answers only."""

    def __init__(self, session: zenoh.Session, robot: str, *, deadline_s: float = DEFAULT_DEADLINE_S,
                 required: frozenset[str] = frozenset({MANAGER_MEMBER}),
                 check: Callable[[Mapping[str, Done]], str] | None = None,
                 wall: Callable[[], float] = time.monotonic, epoch: float | None = None,
                 fleet: list[str] | None = None) -> None:
        self.robot = robot
        robots = list(fleet) if fleet else [robot]
        if robots[0] != robot:
            raise ValueError(f"the fleet's stepper is its first robot's simulator ({robots[0]}), not {robot}'s")
        self.robots = robots
        self.fleet = len(robots) > 1
        if self.fleet:
            required = frozenset({*(f"{r}/{m}" for r in robots for m in required),
                                  *(f"{r}/{FOLLOWER_MEMBER}" for r in robots[1:])})
        self.barrier = Barrier(deadline_s=deadline_s, required=required, release_on_leave=self.fleet)
        if check is not None:
            self.use_check(check)
        self.epoch = time.time() if epoch is None else epoch
        self.step = -1
        self.t = 0.0
        self.rounds = 0
        self._wall = wall
        self._lock = threading.Lock()
        self._inbox: list[Any] = []
        self._ask_at: float | None = None
        """When the next round is due (a member was busy), or None."""
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._clock_pub = session.declare_publisher(clock_key(robot), congestion_control=zenoh.CongestionControl.BLOCK,
                                                    reliability=zenoh.Reliability.RELIABLE)
        self._ask_pubs = [session.declare_publisher(ask_key(r), congestion_control=zenoh.CongestionControl.BLOCK,
                                                    reliability=zenoh.Reliability.RELIABLE,
                                                    priority=zenoh.Priority.DATA) for r in robots]
        self._now = SimTime(step=0, t=0.0, epoch=self.epoch)
        self._entities = [session.declare_queryable(clock_key(robot), self._on_time_query)]
        for r in robots:
            prefix = f"{r}/" if self.fleet else ""
            self._entities += [
                session.declare_subscriber(done_key(r, "*"), lambda sample, p=prefix: self._on_done(sample, p)),
                session.liveliness().declare_subscriber(
                    member_key(r, "*"), lambda sample, p=prefix: self._on_member(sample, p), history=True),
            ]

    def use_check(self, check: Callable[[Mapping[str, Done]], str]) -> None:
        """The stepper's own condition on its robot's answers (in a fleet, the other robots' are not given it:
        another robot's DSP module counts another line)."""
        self.barrier.check = _own_answers(check, self.robot) if self.fleet else check

    @property
    def wake_fd(self) -> int:
        return self._wake_r

    @property
    def members(self) -> set[str]:
        with self._lock:
            self._take()
            return set(self.barrier.members)

    def _on_done(self, sample: zenoh.Sample, prefix: str = "") -> None:
        try:
            done = _decode_done(sample.payload.to_bytes())
        except msgspec.MsgspecError:
            return
        if prefix:  # a fleet: the member named by its robot too (two robots each have a "dsp")
            done = msgspec.structs.replace(done, member=prefix + member_of(str(sample.key_expr)))
        self._hand_over(done)

    def _on_member(self, sample: zenoh.Sample, prefix: str = "") -> None:
        self._hand_over((prefix + member_of(str(sample.key_expr)), sample.kind == zenoh.SampleKind.PUT))

    def _hand_over(self, item: Any) -> None:
        with self._lock:
            self._inbox.append(item)
        try:
            os.write(self._wake_w, b"x")
        except OSError:  # the pipe is full (the loop will look anyway) or closed
            pass

    def drain_wake(self) -> None:
        try:
            while os.read(self._wake_r, 4096):
                pass
        except (BlockingIOError, OSError):
            pass

    def _take(self) -> None:
        items, self._inbox = self._inbox, []
        for item in items:
            if isinstance(item, Done):
                self.barrier.answer(item)
            else:
                name, present = item
                (self.barrier.joined if present else self.barrier.left)(name)

    def _on_time_query(self, query: zenoh.Query) -> None:
        """A process starting in the middle of a simulation asks the time before it handles anything."""
        query.reply(clock_key(self.robot), _encode(self._now))

    def publish_time(self) -> SimTime:
        now = self._now = SimTime(step=max(self.step, 0), t=self.t, epoch=self.epoch)
        self._clock_pub.put(_encode(now))
        return now

    def begin(self, t: float) -> None:
        """Simulated time is now ``t`` (the step's physics is done): tell everyone and ask the first round."""
        self.step += 1
        self.t = t
        with self._lock:
            self._take()
            self.barrier.begin(self.step, self._wall())
        now = self.publish_time()
        self._ask(Ask(step=self.step, round=0, now=now))

    def _ask(self, ask: Ask) -> None:
        self.rounds += 1
        payload = _encode(ask)
        for pub in self._ask_pubs:
            pub.put(payload)

    def poll(self) -> bool:
        """True once the current step is handled; otherwise asks the next round when one is due."""
        if self._ask_at is not None:
            if self._wall() < self._ask_at:
                return False
            self._ask_at = None
            self._ask(Ask(step=self.step, round=self.barrier.round,
                          now=SimTime(step=self.step, t=self.t, epoch=self.epoch)))
            return False
        with self._lock:
            self._take()
            if self.barrier.reask:  # a required member came after this round was asked: it needs the ask
                self.barrier.reask = False
                self._ask(Ask(step=self.step, round=self.barrier.round,
                              now=SimTime(step=self.step, t=self.t, epoch=self.epoch)))
            decision = self.barrier.decide(self._wall())
        if decision.verdict is Verdict.ASK:
            if decision.delay > 0:
                self._ask_at = self._wall() + decision.delay
            else:
                self._ask(Ask(step=self.step, round=decision.round,
                              now=SimTime(step=self.step, t=self.t, epoch=self.epoch)))
            return False
        return decision.verdict is Verdict.STEP

    def timeout(self, idle: float = 0.5) -> float:
        """Wall seconds the caller may block before ``poll`` has something to do (``idle`` when it waits only
        for answers: they wake ``wake_fd``)."""
        if self._ask_at is None:
            return idle
        return max(0.0, self._ask_at - self._wall())

    def close(self) -> None:
        _release([*self._entities, self._clock_pub, *self._ask_pubs], (self._wake_r, self._wake_w), "stepper")


# --- a fleet follower's side -----------------------------------------------------------------------------------


class Follower:
    """A simulator stepping on another robot's barrier (a fleet, ``SimSettings.fleet``), made for a ``select``
    loop as the ``Stepper`` is: a member of its own robot named ``FOLLOWER_MEMBER``, which the fleet's stepper
    requires. ``take()`` gives the newest ask not yet handled (after ``wake_fd`` turned readable): the simulator
    moves its physics to the ask's time, writes what that produced, and ``answer``s with what it has handled and
    its device link's counts (``wire_counts``: the barrier pairs them with the device module's). It also keeps
    its robot's clock: ``@clock`` published each step, and answered to a module starting mid-simulation."""

    def __init__(self, session: zenoh.Session, robot: str) -> None:
        self.robot = robot
        self._lock = threading.Lock()
        self._pending: Ask | None = None
        self._now: SimTime | None = None
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._clock_pub = session.declare_publisher(clock_key(robot), congestion_control=zenoh.CongestionControl.BLOCK,
                                                    reliability=zenoh.Reliability.RELIABLE)
        self._queryable = session.declare_queryable(clock_key(robot), self._on_time_query)
        self._member = Member(session, robot, FOLLOWER_MEMBER, self._on_ask)

    @property
    def wake_fd(self) -> int:
        return self._wake_r

    def _on_ask(self, ask: Ask) -> None:
        with self._lock:
            if self._pending is None or (ask.step, ask.round) >= (self._pending.step, self._pending.round):
                self._pending = ask
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass

    def _on_time_query(self, query: zenoh.Query) -> None:
        now = self._now
        if now is not None:  # before its first step the fleet's time is not known here: no answer (time 0)
            query.reply(clock_key(self.robot), _encode(now))

    def take(self) -> Ask | None:
        try:
            while os.read(self._wake_r, 4096):
                pass
        except (BlockingIOError, OSError):
            pass
        with self._lock:
            ask, self._pending = self._pending, None
        if ask is not None and (self._now is None or ask.now.step != self._now.step):
            self._now = ask.now
            self._clock_pub.put(_encode(ask.now))
        return ask

    def answer(self, ask: Ask, activity: int, counts: dict[str, int]) -> None:
        self._member.answer(ask, activity, "", counts)

    def close(self) -> None:
        self._member.close()
        _release([self._queryable, self._clock_pub], (self._wake_r, self._wake_w), "follower")


def _release(entities: list[Any], fds: tuple[int, ...], what: str) -> None:
    """Undeclare ``entities`` and close the wake pipe's ``fds``, whatever state the session is in."""
    for entity in entities:
        try:
            entity.undeclare()
        except Exception as exc:  # the session may already be closing
            log.debug("lockstep %s close: %s", what, exc)
    for fd in fds:
        try:
            os.close(fd)
        except OSError:
            pass


def frames_due(now_t: float, sim_t: float, dt: float) -> int:
    """A follower's physics sub-steps of ``dt`` that take it from ``sim_t`` to the fleet's ``now_t`` (0 when it
    is there: a later round of the same step). Both times are sums of the same sub-steps, so rounding only
    absorbs the last ulp."""
    return max(0, round((now_t - sim_t) / dt))
