"""The lockstep barrier's rules, with an injected wall time, and one step over a real Zenoh router."""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping

import msgspec
import pytest

from bbcs import keys
from bbcs.clock import SimClock
from bbcs.context import ModuleContext
from bbcs.lockstep import (
    FOLLOWER_MEMBER,
    MANAGER_MEMBER,
    SIM_ENV,
    SLOW_STEP_S,
    Ask,
    Barrier,
    Done,
    Follower,
    Member,
    SimSettings,
    Stepper,
    Verdict,
    current_time,
    frames_due,
    settings_env,
    settings_from_env,
    unpaired_wires,
    wire_counts,
)
from bbcs.module import Module
from bbcs.session import local_client, open_session
from bbcs.slots import InputSlot, Kind
from bbcs.testing import Processes, StepGate, start_router, wait_until


def done(member: str, step: int, rnd: int, activity: int, busy: str = "", **counts: int) -> Done:
    return Done(member=member, step=step, round=rnd, activity=activity, busy=busy, counts=counts)


def barrier(*members: str, **kw) -> Barrier:
    b = Barrier(deadline_s=5.0, **kw)
    for m in members:
        b.joined(m)
    b.begin(0, now=0.0)
    return b


def test_a_step_is_handled_after_two_rounds_with_the_same_activity() -> None:
    b = barrier("a", "b")
    b.answer(done("a", 0, 0, 10))
    assert b.decide(0.1).verdict is Verdict.WAIT  # b has not answered
    b.answer(done("b", 0, 0, 4))
    d = b.decide(0.1)
    assert (d.verdict, d.round) == (Verdict.ASK, 1)  # one quiet round proves nothing was still travelling
    b.answer(done("a", 0, 1, 10))
    b.answer(done("b", 0, 1, 5))  # b handled something between the rounds
    assert b.decide(0.2).verdict is Verdict.ASK
    b.answer(done("a", 0, 2, 10))
    b.answer(done("b", 0, 2, 5))
    assert b.decide(0.3).verdict is Verdict.STEP


def test_answers_to_an_older_round_or_step_do_not_count() -> None:
    b = barrier("a")
    b.answer(done("a", 0, 0, 1))
    assert b.decide(0.0).verdict is Verdict.ASK
    b.answer(done("a", 0, 0, 1))  # a late duplicate of round 0
    assert b.decide(0.0).verdict is Verdict.WAIT


def test_a_busy_member_or_an_unmet_check_keeps_the_step() -> None:
    state = {"sim_tx": 100}

    def check(answers: Mapping[str, Done]) -> str:
        got = answers["dsp"].counts.get("rx", 0)
        return "" if got == state["sim_tx"] else f"dsp read {got} of {state['sim_tx']} bytes"

    b = barrier("dsp", check=check)
    delays = []
    for rnd, (busy, rx) in enumerate([("batch queued", 100), ("", 90), ("", 100)]):
        b.answer(done("dsp", 0, rnd, 7, busy, rx=rx))
        d = b.decide(0.1)
        assert d.verdict is Verdict.ASK
        delays.append(d.delay)
    assert delays[0] > 0 and delays[1] > delays[0] and delays[2] == 0  # a busy member is not asked in a tight loop
    b.answer(done("dsp", 0, 3, 7, rx=100))
    assert b.decide(0.1).verdict is Verdict.STEP


def test_a_step_not_handled_after_a_few_seconds_is_logged_once_with_its_cause(caplog) -> None:
    b = Barrier(deadline_s=60.0)
    b.joined("a")
    b.joined("pan_tilt")
    b.begin(0, now=100.0)
    b.answer(done("a", 0, 0, 1))
    with caplog.at_level("WARNING", logger="bbcs.lockstep"):
        assert b.decide(100.0 + SLOW_STEP_S - 0.1).verdict is Verdict.WAIT
        assert not caplog.records  # not slow yet
        for t in (SLOW_STEP_S + 0.1, SLOW_STEP_S + 1.0):
            assert b.decide(100.0 + t).verdict is Verdict.WAIT
    assert [r.getMessage() for r in caplog.records] == [
        f"lockstep: step 0 not handled after {SLOW_STEP_S + 0.1:.1f} s of wall: waiting for ['pan_tilt']"]


def test_a_required_member_is_waited_for_without_a_deadline() -> None:
    b = barrier(required=frozenset({MANAGER_MEMBER}))
    assert b.decide(100.0).verdict is Verdict.WAIT  # not even present yet
    b.joined(MANAGER_MEMBER)
    b.joined("slow")
    b.answer(done(MANAGER_MEMBER, 0, 0, 1, "modules starting"))
    assert b.decide(100.0).verdict is Verdict.ASK  # busy, far past the deadline: still waited for
    b.answer(done(MANAGER_MEMBER, 0, 1, 1))
    assert b.decide(104.0).verdict is Verdict.WAIT  # the deadline runs from when the manager stopped holding the step


def test_a_silent_member_is_left_behind_at_the_deadline_and_waited_for_again_once_it_answers() -> None:
    b = barrier("a", "hung")
    b.answer(done("a", 0, 0, 1))
    assert b.decide(4.9).verdict is Verdict.WAIT
    d = b.decide(5.1)
    assert (d.verdict, d.left_behind) == (Verdict.STEP, ["hung"])
    b.begin(1, now=6.0)
    assert b.expected() == {"a"}
    b.answer(done("a", 1, 0, 1))
    assert b.decide(6.0).verdict is Verdict.ASK
    b.answer(done("hung", 0, 7, 3))  # its answer to an old step: it is back, waited for again
    assert b.expected() == {"a", "hung"}
    assert b.decide(6.1).verdict is Verdict.WAIT
    b.answer(done("a", 1, 1, 1))
    b.answer(done("hung", 1, 1, 3))  # the answer that brings a member back also counts
    b.left("a")
    assert b.decide(6.2).verdict is Verdict.ASK


def test_a_member_that_joins_during_a_round_is_waited_for_from_the_next_one() -> None:
    b = barrier("a")
    b.joined("late")  # its token came after the round's ask went out: it never got it
    b.answer(done("a", 0, 0, 1))
    d = b.decide(0.1)
    assert d.verdict is Verdict.ASK
    b.answer(done("a", 0, 1, 1))
    assert b.decide(0.2).verdict is Verdict.WAIT  # asked this round: its answer is needed
    b.answer(done("late", 0, 1, 0))
    assert b.decide(0.2).verdict is Verdict.ASK  # a new member changes the picture: one more quiet round


def test_a_member_that_leaves_is_no_longer_waited_for() -> None:
    b = barrier("a", "dead")
    b.answer(done("a", 0, 0, 1))
    b.left("dead")
    assert b.decide(0.1).verdict is Verdict.ASK


def test_a_required_member_that_comes_after_the_ask_is_asked_again() -> None:
    """A fleet's other robot launched after the fleet's first step was asked: its manager never got that ask."""
    b = barrier("a", required=frozenset({"r2/manager"}))
    assert not b.reask
    b.joined("r2/manager")
    assert b.reask  # the stepper asks the round again
    b.answer(done("a", 0, 0, 1))
    b.answer(done("r2/manager", 0, 0, 1))
    assert b.decide(0.1).verdict is Verdict.ASK
    b.begin(1, now=0.2)
    assert not b.reask  # a new step's first round goes to everyone
    b.joined("later")  # not required: waited for from the next round, as before
    assert not b.reask


def test_in_a_fleet_a_required_member_that_leaves_is_released_and_alone_it_is_not() -> None:
    fleet = barrier("a", "r2/manager", required=frozenset({"r2/manager"}), release_on_leave=True)
    fleet.left("r2/manager")  # its robot killed: the fleet flies on
    fleet.answer(done("a", 0, 0, 1))
    assert fleet.decide(0.1).verdict is Verdict.ASK
    fleet.answer(done("a", 0, 1, 1))
    assert fleet.decide(0.2).verdict is Verdict.STEP
    alone = barrier("a", MANAGER_MEMBER, required=frozenset({MANAGER_MEMBER}))
    alone.left(MANAGER_MEMBER)  # a robot without its manager has nothing to step for
    alone.answer(done("a", 0, 0, 1))
    assert alone.decide(100.0).verdict is Verdict.WAIT


def test_a_follower_moves_to_the_fleets_time_in_whole_physics_steps() -> None:
    t = 0.0
    for _ in range(10):
        t += 0.02
    assert frames_due(t, 0.0, 0.02) == 10  # the leader's summed time: rounding absorbs the last ulp
    assert frames_due(t, t, 0.02) == 0  # a later round of the same step
    assert frames_due(0.0, t, 0.02) == 0  # never backwards


def test_the_fleets_stepper_asks_every_robots_members_and_a_follower_keeps_its_robots_clock() -> None:
    """A real router: the leader's stepper (robot r1) waits for r2's manager and follower as well as its own
    members, each robot's members on their own keys; a member named alike on both robots counts twice; the
    follower's robot's @clock says the leader's time."""
    procs = Processes()
    sessions = []
    try:
        cfg = local_client(start_router(procs))
        sessions = [open_session(cfg) for _ in range(5)]
        stepper = Stepper(sessions[0], "r1", fleet=["r1", "r2"], check=lambda answers: (
            "" if set(answers) <= {MANAGER_MEMBER, "dsp"} else f"not its own robot's: {sorted(answers)}"))
        assert stepper.barrier.required == {"r1/manager", "r2/manager", f"r2/{FOLLOWER_MEMBER}"}
        seen: dict[str, list[Ask]] = {}
        members = {}
        for s, (robot, name) in zip(sessions[1:4], [("r1", MANAGER_MEMBER), ("r2", MANAGER_MEMBER), ("r2", "dsp")],
                                    strict=True):
            def on_ask(ask: Ask, key: str = f"{robot}/{name}") -> None:
                seen.setdefault(key, []).append(ask)
                members[key].answer(ask, activity=1)
            members[f"{robot}/{name}"] = Member(s, robot, name, on_ask)
        follower = Follower(sessions[4], "r2")
        wait_until(lambda: stepper.members >= {"r1/manager", "r2/manager", "r2/dsp", f"r2/{FOLLOWER_MEMBER}"}, 10,
                   "every robot's members")
        stepper.begin(0.2)
        for _ in range(20):  # the follower has not answered: the step waits for it
            assert not stepper.poll()
            threading.Event().wait(0.01)
        asks = []
        wait_until(lambda: (a := follower.take()) is not None and asks.append(a) is None, 10, "the follower asked")
        follower.answer(asks[-1], 1, {})

        def handled() -> bool:
            if (a := follower.take()) is not None:
                follower.answer(a, 1, {})
            return stepper.poll()

        wait_until(handled, 10, "the step handled")
        assert {k: {a.step for a in v} for k, v in seen.items()} == {"r1/manager": {0}, "r2/manager": {0},
                                                                      "r2/dsp": {0}}
        assert current_time(sessions[1], "r2") == current_time(sessions[1], "r1") == asks[-1].now
        assert asks[-1].now.t == 0.2
        follower.close()
        for m in members.values():
            m.close()
        stepper.close()
    finally:
        for s in sessions:
            s.close()
        procs.stop_all()


def wired(member: str, step: int, rnd: int, activity: int, busy: str = "", **links: tuple[int, int]) -> Done:
    counts: dict[str, int] = {}
    for link, (tx, rx) in links.items():
        counts.update(wire_counts(link, tx, rx))
    return Done(member=member, step=step, round=rnd, activity=activity, busy=busy, counts=counts)


def test_a_device_link_pairs_what_one_end_wrote_with_what_the_other_read() -> None:
    def answers(*dones: Done) -> dict[str, Done]:
        return {d.member: d for d in dones}

    assert unpaired_wires(answers(wired("sim", 0, 0, 0, mtig=(120, 30)),
                                  wired("logger", 0, 0, 0, mtig=(30, 120)))) == ""
    # a scan written by the simulator and not yet read by the logger
    unmet = unpaired_wires(answers(wired("sim", 0, 0, 0, ldmrs=(5000, 40)), wired("logger", 0, 0, 0, ldmrs=(40, 4200))))
    assert unmet == "link ldmrs: logger wrote 40 B (sim read 40), sim wrote 5000 B (logger read 4200)"
    # a request written by the logger and not yet handled by the simulator
    assert "link mtig" in unpaired_wires(answers(wired("sim", 0, 0, 0, mtig=(120, 30)),
                                                 wired("logger", 0, 0, 0, mtig=(36, 120))))
    # each link on its own: one settled, the other not
    unmet = unpaired_wires(answers(wired("sim", 0, 0, 0, mtig=(120, 30), ldmrs=(10, 2)),
                                   wired("logger", 0, 0, 0, mtig=(30, 120), ldmrs=(2, 9))))
    assert unmet.startswith("link ldmrs:") and "mtig" not in unmet
    # one end alone (its other end not a member, or left behind), three ends, other counts: not judged
    assert unpaired_wires(answers(wired("sim", 0, 0, 0, mtig=(120, 30)))) == ""
    assert unpaired_wires(answers(wired("a", 0, 0, 0, x=(1, 0)), wired("b", 0, 0, 0, x=(0, 0)),
                                  wired("c", 0, 0, 0, x=(0, 0)))) == ""
    assert unpaired_wires(answers(done("dsp", 0, 0, 0, dsp_bytes_tx=10, dsp_bytes_rx=3),
                                  done("x", 0, 0, 0, dsp_bytes_tx=1, dsp_bytes_rx=2))) == ""


def test_a_step_waits_until_both_ends_of_a_device_link_agree() -> None:
    b = barrier("lidar_sim", "lidar_logger")
    b.answer(wired("lidar_sim", 0, 0, 100, mtig=(100, 24), ldmrs=(9000, 64)))
    b.answer(wired("lidar_logger", 0, 0, 7, mtig=(24, 100), ldmrs=(64, 4000)))  # half a scan read
    d = b.decide(0.1)
    assert d.verdict is Verdict.ASK and "link ldmrs" in d.why and d.delay > 0  # asked again after a pause
    for rnd in (1, 2):  # the logger has read the scan: two quiet rounds, then the step
        b.answer(wired("lidar_sim", 0, rnd, 100, mtig=(100, 24), ldmrs=(9000, 64)))
        b.answer(wired("lidar_logger", 0, rnd, 8, mtig=(24, 100), ldmrs=(64, 9000)))
        d = b.decide(0.2 + rnd)
    assert d.verdict is Verdict.STEP
    # a stepper's own check and the links' rule both hold the step, and both are named
    b = barrier("lidar_sim", "lidar_logger", check=lambda answers: "DSP line: 3 B unread")
    b.answer(wired("lidar_sim", 0, 0, 1, mtig=(10, 0)))
    b.answer(wired("lidar_logger", 0, 0, 1, mtig=(0, 4)))
    d = b.decide(0.1)
    assert d.verdict is Verdict.ASK and d.why == ("DSP line: 3 B unread; link mtig: lidar_logger wrote 0 B "
                                                  "(lidar_sim read 0), lidar_sim wrote 10 B (lidar_logger read 4)")


def test_settings_travel_in_the_environment() -> None:
    s = SimSettings(robot="uav1", connect=["tcp/127.0.0.1:1"], speed=None, step_s=0.1)
    assert settings_from_env(settings_env(s)) == s
    assert settings_from_env({}) is None
    with pytest.raises(ValueError, match="CROMAT_SIM"):
        settings_from_env({"CROMAT_SIM": "{"})


def test_a_step_over_the_bus_waits_for_every_member() -> None:
    """A real router: the stepper's step is handled only after both members answered two quiet rounds."""
    procs = Processes()
    sessions = []
    try:
        cfg = local_client(start_router(procs))
        sessions = [open_session(cfg) for _ in range(3)]
        clocks = {"m1": SimClock(), "m2": SimClock()}
        held: list[Ask] = []
        members: dict[str, Member] = {}

        def on_ask(name: str, ask: Ask) -> None:
            clocks[name].advance(ask.now)
            if name == "m2" and ask.round == 0:
                held.append(ask)  # m2 answers round 0 only when the test says so
                return
            members[name].answer(ask, activity=1)

        for s, name in zip(sessions[1:], clocks, strict=True):
            members[name] = Member(s, "r1", name, lambda ask, n=name: on_ask(n, ask))
        stepper = Stepper(sessions[0], "r1", required=frozenset())
        wait_until(lambda: stepper.members == {"m1", "m2"}, 10, "both members' tokens")
        stepper.begin(0.1)
        wait_until(lambda: held, 10, "m2 asked")
        for _ in range(20):
            assert not stepper.poll()
            threading.Event().wait(0.01)
        members["m2"].answer(held[0], activity=1)
        wait_until(stepper.poll, 10, "the step handled")
        assert clocks["m1"].monotonic() == clocks["m2"].monotonic() == 0.1
        assert stepper.rounds >= 2
        stepper.close()
        for m in members.values():
            m.close()
    finally:
        for s in sessions:
            s.close()
        procs.stop_all()


def test_a_test_gate_holds_the_simulation_while_closed(router: int, sessions) -> None:  # noqa: ANN001
    """``bbcs.testing.StepGate`` over a real router: open, every step goes through; closed, the step under way
    is not handled (however long: up to the deadline); opened again, it is."""
    stepper_session, gate_session = sessions(), sessions()
    stepper = Stepper(stepper_session, "r1", required=frozenset())
    gate = StepGate(gate_session, "r1")
    try:
        wait_until(lambda: stepper.members == {StepGate.NAME}, 10, "the gate's token")

        def step(t: float) -> None:
            stepper.begin(t)
            wait_until(stepper.poll, 10, f"the step to {t:g} s handled")

        step(0.2)
        step(0.4)
        with gate.closed():
            stepper.begin(0.6)
            for _ in range(50):  # half a second of wall: the gate answers nothing
                assert not stepper.poll()
                threading.Event().wait(0.01)
        wait_until(stepper.poll, 10, "the held step handled once the gate opened")
        step(0.8)
    finally:
        gate.leave()
        stepper.close()


class Reading(msgspec.Struct, frozen=True, kw_only=True):
    n: int


class Ticker(Module):
    """Ticks every 0.5 s of its clock; a handler that takes 0.3 s of wall."""

    name = "ticker"
    slots = (InputSlot("reading", Reading, kind=Kind.STREAM),)
    tick_period = 0.5

    def on_start(self) -> None:
        self.ticks: list[float] = []
        self.handled: list[int] = []

    def on_tick(self) -> None:
        self.ticks.append(self.bbcs_clock.monotonic())

    def on_reading(self, value: Reading) -> None:
        time.sleep(0.3)
        self.handled.append(value.n)


def test_a_module_runs_on_simulated_time_and_answers_only_once_idle(router: int, sessions,  # noqa: ANN001
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """A real Module under CROMAT_SIM: its ticks and heartbeat follow the stepper's time, not the wall, and its
    answer to an ask comes only after the datum it was handling (the step waits for it)."""
    monkeypatch.setenv(SIM_ENV, msgspec.json.encode(SimSettings(robot="r1")).decode())
    mod = Ticker(ModuleContext(robot="r1", module="ticker", bus=local_client(router)))
    assert isinstance(mod.bbcs_clock, SimClock)
    loop = threading.Thread(target=mod.run, daemon=True)
    loop.start()
    s = sessions()
    beats: list[float] = []
    s.declare_subscriber(keys.heartbeat_key("r1", "ticker"), lambda _sample: beats.append(mod.bbcs_clock.monotonic()))
    stepper = Stepper(s, "r1", required=frozenset())
    try:
        wait_until(lambda: stepper.members == {"ticker"}, 10, "the module's member token")
        time.sleep(0.6)
        assert mod.ticks == [] and len(beats) <= 1  # the wall moves, simulated time does not: no tick, one beat
        pub = s.declare_publisher(keys.slot_key("r1", "ticker", "reading"))
        for step in range(1, 13):  # 1.2 s of simulated time in steps of 0.1 s
            if step == 3:
                pub.put(msgspec.msgpack.encode(Reading(n=7)))
                wait_until(lambda: mod._activity > 0 or mod.handled, 5, "the datum taken")
            stepper.begin(round(step * 0.1, 3))
            wait_until(stepper.poll, 10, f"step {step} handled")
            if step == 3:
                assert mod.handled == [7]  # the step was handled only once the datum was
        assert mod.ticks == [0.5, 1.0]
        assert any(1.0 <= b <= 1.2 for b in beats) and len(beats) <= 2  # one beat a simulated second
    finally:
        mod.request_stop()
        loop.join(10)
        stepper.close()


class Starter(Module):
    """Notes the time its clock reads when it starts, before it takes any input."""

    name = "starter"
    slots = ()

    def on_start(self) -> None:
        self.started_at = self.bbcs_clock.monotonic()
        self.stamped_at = self.bbcs_clock.time()


def test_a_module_started_mid_simulation_reads_its_time_before_anything_else(router: int, sessions,  # noqa: ANN001
                                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """A module (re)started when the simulation is already 42.4 s in starts on that time, not on 0: a restarted RAL
    that saw its tasks again from the manager's task book judged them as started at 0 and failed one at once for
    "no progress for 3201 s" (the campaign, seed 23). With no stepper (the simulation not begun) it starts at 0."""
    monkeypatch.setenv(SIM_ENV, msgspec.json.encode(SimSettings(robot="r1")).decode())
    s = sessions()
    stepper = Stepper(s, "r1", required=frozenset(), epoch=1_000_000.0)
    mods: list[Starter] = []
    loops: list[threading.Thread] = []
    try:
        for step in range(1, 5):
            stepper.begin(round(10.6 * step, 3))
            wait_until(stepper.poll, 10, f"step {step} handled")
        for robot in ("r1", "r2"):  # r2: no stepper answers
            mod = Starter(ModuleContext(robot=robot, module="starter", bus=local_client(router)))
            mods.append(mod)
            loops.append(threading.Thread(target=mod.run, daemon=True))
            loops[-1].start()
        wait_until(lambda: all(hasattr(m, "started_at") for m in mods), 15, "both modules started")
        assert (mods[0].started_at, mods[0].stamped_at) == (42.4, 1_000_042.4)
        assert mods[1].started_at == 0.0
    finally:
        for mod in mods:
            mod.request_stop()
        for loop in loops:
            loop.join(10)
        stepper.close()
