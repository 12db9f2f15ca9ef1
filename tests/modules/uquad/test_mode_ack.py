"""The uQuad flight module answers each mode only once the flight loop's inbox holds it, and the shipped manifest
waits for that answer: the RAL's path for a goto is then queued behind the goto's mode (a hold's mode arriving after
the path would clear the waypoints, and the goto would hover)."""

from __future__ import annotations

import queue
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from bbcs.contracts.error_codes import UquadErrorCode
from bbcs.contracts.mri import MODE_ACK_SLOT, ModeAck
from module_manager.manifest import load_manifest
from modules.uquad.module import UquadModule
from modules.uquad.planner import Mode
from modules.uquad.structs import UquadMode

CONF = Path(__file__).resolve().parents[3] / "bbcs_conf"


def flight_module(driver_error: str = "") -> tuple[Any, list[tuple[str, Any, list[Any]]]]:
    """The module's mode handler's state: its inbox, its driver error, and what it published (with the inbox's
    content at that moment)."""
    sent: list[tuple[str, Any, list[Any]]] = []
    inbox: queue.Queue[tuple[str, Any]] = queue.Queue()
    mod = SimpleNamespace(driver_error=driver_error, _inbox=inbox)
    mod.publish = lambda slot, value: sent.append((slot, value, list(inbox.queue)))
    return mod, sent


def test_a_mode_is_answered_after_it_is_queued() -> None:
    mod, sent = flight_module()
    UquadModule.on_modo(mod, UquadMode(modo=0))
    UquadModule.on_modo(mod, UquadMode(modo=1))
    assert [(s, a) for s, a, _ in sent] == [(MODE_ACK_SLOT, ModeAck(mode={"modo": 0}, accepted=True)),
                                            (MODE_ACK_SLOT, ModeAck(mode={"modo": 1}, accepted=True))]
    assert sent[0][2] == [("mode", Mode.HOLD)]
    assert sent[1][2] == [("mode", Mode.HOLD), ("mode", Mode.GOTO)]


def test_after_a_driver_error_only_a_landing_is_taken() -> None:
    mod, sent = flight_module("motor 2: no ack in 0.1 s")
    UquadModule.on_modo(mod, UquadMode(modo=1))
    [(slot, ack, queued)] = sent
    assert slot == MODE_ACK_SLOT and queued == []
    assert not ack.accepted and ack.code == UquadErrorCode.DRIVER_ERROR and "only a landing" in ack.reason
    UquadModule.on_modo(mod, UquadMode(modo=3))
    assert sent[-1][1].accepted and list(mod._inbox.queue) == [("mode", Mode.LAND)]


def test_the_shipped_manifest_waits_for_the_answer() -> None:
    m = load_manifest(CONF / "uquad1_sim.toml")
    assert m.modes["uquad_mode"].ack


def test_a_late_driver_ack_on_the_ground_clears_once_the_driver_answers_in_time_again() -> None:
    """One ack late on a loaded computer grounded the uQuad until its process restarted (test_fleet_mixed in a
    clean-clone run: "mode TAKE_OFF refused after a driver error (no ack for command 1120 within 500 ms)").
    The flight loop's ``_command`` with a real driver link (a socket pair): the late ack is reported and takes
    the landing action; on the ground, with the motors stopped and every command answered in time for
    ``RECOVERY_S``, a take-off is taken again. In the air it is never cleared."""
    import socket

    import numpy as np

    from modules.uquad import motor_protocol as mp
    from modules.uquad.config import load_config
    from modules.uquad.motor_client import RECOVERY_S, MotorClient

    ack_timeout = load_config(CONF / "uquad1.conf").values.MOTOR_ACK_TIMEOUT  # the shipped value
    late = ack_timeout + 0.1
    a, b = socket.socketpair()
    motor = MotorClient(a, 300, 750, ack_timeout_s=ack_timeout)
    errors: list[tuple[int, str]] = []
    modes: list[Mode] = []
    planner = SimpleNamespace(mode=Mode.IDLE)
    mod, sent = flight_module()
    mod.__dict__.update(
        lockstep=True, ledger=SimpleNamespace(motor_tx=0), latencies=[],
        cfg=SimpleNamespace(values=SimpleNamespace(MOTOR_ERROR_ACTION="land")),
        core=SimpleNamespace(planner=planner, set_mode=modes.append, stats=SimpleNamespace(last_ts=0)),
        report_error=lambda code, detail: errors.append((int(code), detail)),
        log=SimpleNamespace(warning=lambda *args: None), _send=lambda *args: None, _stamp=lambda now: now)
    mod._link_now = lambda now: now

    def step(now: float, answer: bool = True) -> None:
        UquadModule._command(mod, np.zeros(4), now, 0.0, motor)
        if answer:
            for seq in list(motor.pending):
                b.sendall(mp.ack(seq, mp.AckStatus.STOPPED))

    try:
        step(0.0, answer=False)
        step(late)  # command 1 unanswered past the timeout: a driver error, reported, and the landing action taken
        assert mod.driver_error.startswith("no ack for command 1") and modes == [Mode.LAND]
        assert errors and errors[0][0] == UquadErrorCode.DRIVER_ERROR
        UquadModule.on_modo(mod, UquadMode(modo=2))
        assert not sent[-1][1].accepted  # take-off refused while the error stands
        b.sendall(mp.ack(1, mp.AckStatus.STOPPED))  # its ack comes after all
        t = late
        while t < late + RECOVERY_S + 0.5:
            t = round(t + 0.02, 2)
            step(t)
            if t < late + RECOVERY_S - 0.1:
                assert mod.driver_error, f"cleared after {t - late:.2f} s"
        assert mod.driver_error == "" and len(errors) == 1
        UquadModule.on_modo(mod, UquadMode(modo=2))
        assert sent[-1][1].accepted and list(mod._inbox.queue)[-1] == ("mode", Mode.TAKE_OFF)

        planner.mode = Mode.HOLD  # in the air: a late ack stays an error however well the driver answers after
        step(t + 0.1, answer=False)
        step(t + 0.1 + late)
        assert mod.driver_error
        b.sendall(mp.ack(motor.seq - 1, mp.AckStatus.STOPPED))
        for i in range(1, 200):
            step(t + 0.1 + late + 0.02 * i)
        assert mod.driver_error
    finally:
        a.close()
        b.close()
