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
