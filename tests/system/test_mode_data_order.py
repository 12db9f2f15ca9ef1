"""Issue 11 case 11: a mode change and the data it governs reach the module in order.

The pan & tilt module reads its mode and its data on two inputs (two reader threads, nothing ordering them).
With the mode delayed (injected: published 0.5 s late, as a slow sender would), data sent at once are handled
under the previous mode: angles 0/0 reach the DSP. The fix is a barrier (docs/bus.md, "Mode and data in order"):
the module answers each mode on ``mode_ack`` after applying it, the Module Manager waits for that answer before it
replies to the task, and the RAL publishes the task's data only after the reply. Replaying the same delay with the
barrier, the DSP receives the mode and then the target, never angles.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator

import msgspec
import pytest

from bbcs import keys
from bbcs.contracts import dsp as p
from bbcs.contracts.mri import MODE_ACK_SLOT, ModeAck
from bbcs.contracts.pan_tilt import DatosPT, ModoFuncionamientoPT

from .uav_stack import ROBOT, Stack, wait_until

PT = "pan_tilt"
DELAY_S = 0.5
TARGET = DatosPT(latitud=37.4127, longitud=-6.0025, altura=12.0)  # look_at's datum: its angles are 0/0


@pytest.fixture
def uav(tmp_path) -> Iterator[Stack]:
    stack = Stack(tmp_path, [PT])
    try:
        yield stack.start()
    finally:
        stack.close()


def mode(m: int) -> ModoFuncionamientoPT:
    return ModoFuncionamientoPT(modo_de_funcionamiento=m)


def angles_mode(uav: Stack) -> None:
    mark = uav.mark()
    uav.send("pt_modo", mode(0))
    uav.expect(mark, [p.SetPanTiltMode(mode=p.PanTiltMode.ANGLES)], "pan & tilt in mode 0 (angles)")


def test_case11_mode_and_data_in_order(uav: Stack) -> None:
    acks: list[ModeAck] = []
    sub = uav.session.declare_subscriber(
        keys.slot_key(ROBOT, PT, MODE_ACK_SLOT),
        lambda s: acks.append(msgspec.msgpack.decode(s.payload.to_bytes(), type=ModeAck)),
    )
    try:
        # the race, reproduced: mode 1 late, its datum at once
        angles_mode(uav)
        mark = uav.mark()
        late = threading.Timer(DELAY_S, uav.send, ("pt_modo", mode(1)))
        late.start()
        uav.send("pt_gcs", TARGET)
        late.join()
        wait_until(lambda: any(r["name"] == "SET_PT_MODE" for r in uav.received(mark)), 15, "the late mode")
        uav.barrier()
        raced = [(r["name"], r["fields"]) for r in uav.received(mark)]
        assert raced[0][0] == "SET_PT_ANGLES" and raced[0][1]["pan_deg"] == 0.0 and raced[0][1]["tilt_deg"] == 0.0, (
            f"the race did not show: {raced}"
        )

        # the same delay with the barrier: the datum goes only after the module answered the new mode
        angles_mode(uav)
        mark = uav.mark()
        seen = len(acks)
        late = threading.Timer(DELAY_S, uav.send, ("pt_modo", mode(1)))
        late.start()
        wait_until(lambda: any(a.mode == {"modo_de_funcionamiento": 1} and a.accepted for a in acks[seen:]), 15,
                   "the module's answer to mode 1")
        late.join()
        uav.send("pt_gcs", TARGET)
        # the barrier's PING proves only what the module had published before it: wait for the datum's command
        wait_until(lambda: any(r["name"].startswith("SET_PT_") and r["name"] != "SET_PT_MODE"
                               for r in uav.received(mark)), 15, "the datum's command at the DSP")
        uav.barrier()
        ordered = [r["name"] for r in uav.received(mark)]
        assert ordered == ["SET_PT_MODE", "SET_PT_TARGET"], ordered
    finally:
        sub.undeclare()
