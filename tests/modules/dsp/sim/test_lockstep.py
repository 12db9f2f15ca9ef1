"""The DSP simulator as a lockstep stepper (docs/simulation.md): on a real router, with a real DspLink on its TCP
line and a stand-in manager member, simulated time moves only once every member has answered a quiet round, a
command is acknowledged while the step waits (simulated time standing still), and ``speed`` paces the steps."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest

from bbcs.clock import SimClock
from bbcs.contracts import dsp as p
from bbcs.lockstep import MANAGER_MEMBER, Ask, Member, Stepper, wire_counts
from bbcs.session import local_client, open_session
from bbcs.testing import Processes, start_router, wait_until
from modules.dsp.link import DspLink, lockstep_link
from modules.dsp.sim import DspSimulator
from modules.dsp.sim.transport import TcpEndpoint

ROBOT = "r1"


class StandIn:
    """A member that answers every ask unless ``hold`` is set; its activity is what the test says."""

    def __init__(self, session, name: str, counts=None) -> None:  # noqa: ANN001 - a test double
        self.clock = SimClock()
        self.hold = threading.Event()
        self.activity = 0
        self.counts = counts or (lambda: {})
        self.held: list[Ask] = []
        self.member = Member(session, ROBOT, name, self._on_ask)

    def _on_ask(self, ask: Ask) -> None:
        self.clock.advance(ask.now)
        if self.hold.is_set():
            self.held.append(ask)
            return
        self.member.answer(ask, self.activity, counts=self.counts())


@pytest.fixture
def bus() -> Iterator[list]:
    procs = Processes()
    sessions: list = []
    try:
        cfg = local_client(start_router(procs))
        sessions.extend(open_session(cfg) for _ in range(3))
        yield sessions
    finally:
        for s in sessions:
            s.close()
        procs.stop_all()


def start_sim(session, *, speed: float | None, deadline_s: float = 20.0) -> DspSimulator:  # noqa: ANN001
    stepper = Stepper(session, ROBOT, deadline_s=deadline_s)
    return DspSimulator(TcpEndpoint(), stepper=stepper, frame_s=0.1, speed=speed).start()


def test_time_moves_only_when_every_member_has_answered(bus: list) -> None:
    manager = StandIn(bus[1], MANAGER_MEMBER)
    manager.hold.set()  # the manager holds the first step: nothing may move
    sim = start_sim(bus[0], speed=None)
    try:
        wait_until(lambda: manager.held, 10, "the first ask")
        time.sleep(0.3)
        assert sim.machine.time_s == 0.0 and manager.clock.monotonic() == 0.0
        manager.hold.clear()
        manager.member.answer(manager.held[-1], 0)
        wait_until(lambda: sim.machine.time_s >= 1.0, 20, "simulated time moving once the manager answered")
        assert abs(manager.clock.monotonic() - round(manager.clock.monotonic(), 1)) < 1e-6  # whole frames of 0.1 s
        manager.hold.set()
        held_at = len(manager.held)
        wait_until(lambda: len(manager.held) > held_at, 10, "an ask held")
        t = sim.machine.time_s
        time.sleep(0.3)
        assert sim.machine.time_s == t  # a member that does not answer stops the simulation (until the deadline)
    finally:
        manager.hold.clear()
        sim.stop()
        sim.stepper.close()
        manager.member.close()
    assert sim.error is None


def test_a_command_is_acknowledged_while_the_step_waits_and_the_line_is_counted(bus: list) -> None:
    manager = StandIn(bus[1], MANAGER_MEMBER)
    sim = start_sim(bus[0], speed=None)
    link_clock = SimClock()
    link = DspLink(f"socket://127.0.0.1:{sim.endpoint.port}", ack_timeout=0.25, retries=0,  # type: ignore[attr-defined]
                   clock=link_clock)
    dsp = StandIn(bus[2], "dsp", counts=lambda: wire_counts(lockstep_link(ROBOT), link.stats().bytes_tx,
                                                            link.bytes_handled))
    try:
        wait_until(lambda: sim.machine.time_s >= 0.3, 20, "steps with the DSP member answering")
        manager.hold.set()  # the simulation stands still from the next ask on
        held_at = len(manager.held)
        wait_until(lambda: len(manager.held) > held_at, 10, "an ask held")
        t = sim.machine.time_s
        ack = link.send(p.SetTelemetryMask(mask=int(p.TelemetryField.POSITION)))  # answered with time frozen
        assert ack.status == 0 and sim.machine.time_s == t
        assert sim.commands[-1].name == "SET_TELEMETRY_MASK" and sim.commands[-1].t_sim == t
        manager.hold.clear()
        manager.member.answer(manager.held[-1], 0)
        wait_until(lambda: sim.machine.time_s >= t + 0.5, 20, "steps again")
        wait_until(lambda: sim.line_tx == link.bytes_handled and sim.line_rx == link.stats().bytes_tx, 10,
                   "the line's byte counts agreeing both ways")
    finally:
        manager.hold.clear()
        sim.stop()
        link.close()
        sim.stepper.close()
        for m in (manager, dsp):
            m.member.close()
    assert sim.error is None


def test_speed_paces_the_steps(bus: list) -> None:
    manager = StandIn(bus[1], MANAGER_MEMBER)
    sim = start_sim(bus[0], speed=2.0)
    try:
        wait_until(lambda: sim.machine.time_s >= 0.1, 20, "the first step")
        t0, w0 = sim.machine.time_s, time.monotonic()
        wait_until(lambda: sim.machine.time_s >= t0 + 1.0, 20, "one simulated second")
        assert time.monotonic() - w0 >= 1.0 / 2.0 - 0.1  # no faster than twice real time
    finally:
        sim.stop()
        sim.stepper.close()
        manager.member.close()
