"""Issue 30 case 5 at the bus level: an unsafe state input routed back to a source gets that source's current value
(a safe state publisher's cache), not only what the source publishes next; a best-effort source keeps nothing,
so nothing is replayed from it; a stream is never replayed. A real router, the module's own loop in a thread."""

from __future__ import annotations

import threading
import time

import msgspec
import pytest

from bbcs import keys
from bbcs.codec import type_name
from bbcs.context import ModuleContext
from bbcs.module import Control, Module
from bbcs.module_inputs import rereads
from bbcs.routing import SlotRef, SlotTable
from bbcs.session import local_client
from bbcs.slots import Direction, InputSlot, Kind, OutputSlot, Publisher, Safety, SlotSpec
from bbcs.testing import wait_until

ROBOT = "r1"


class Point(msgspec.Struct, frozen=True, kw_only=True):
    name: str


class Entrada(msgspec.Struct, frozen=True, kw_only=True):
    slot_entrada_datos: int


class Gimbal(Module):
    """An unsafe state input (as pan & tilt's DATOS), routed by its CONTROL_ENTRADA."""

    name = "gimbal"
    slots = (InputSlot("datos", Point, safety=Safety.UNSAFE),)
    control = Control(Entrada, {"slot_entrada_datos": "datos"})

    def on_start(self) -> None:
        self.seen: list[str] = []

    def on_datos(self, value: Point) -> None:
        self.seen.append(value.name)


def test_which_inputs_reread_their_source() -> None:
    assert rereads(InputSlot("a", Point, safety=Safety.UNSAFE))
    assert not rereads(InputSlot("b", Point))  # safe state: its history gives the last value already
    assert not rereads(InputSlot("c", Point, kind=Kind.STREAM))


@pytest.mark.timeout(60)
def test_routing_back_to_a_source_brings_its_current_value(router: int, sessions) -> None:
    s = sessions()
    table = SlotTable(robot=ROBOT, slots={
        1: SlotRef(module="ral", slot="datos", type=type_name(Point)),
        2: SlotRef(module="vision", slot="target", type=type_name(Point))})
    ral = Publisher(s, keys.slot_key(ROBOT, "ral", "datos"), OutputSlot("datos", Point))  # safe state: kept
    vision = Publisher(s, keys.slot_key(ROBOT, "vision", "target"),
                       OutputSlot("target", Point, safety=Safety.UNSAFE))  # best effort: nothing kept
    control = Publisher(s, keys.slot_key(ROBOT, "gimbal", "control_entrada"),
                        SlotSpec("control_entrada", Entrada, Direction.OUT, Kind.STATE, Safety.SAFE))
    gimbal = Gimbal(ModuleContext(robot=ROBOT, module="gimbal", bus=local_client(router), slot_table=table,
                                  routes={"datos": 1}))
    thread = threading.Thread(target=gimbal.run, daemon=True)
    thread.start()
    try:
        wait_until(lambda: hasattr(gimbal, "seen") and gimbal._running, 20, "the module running")
        time.sleep(0.5)  # its subscription reaches the router
        ral.publish(Point(name="look_at"))
        wait_until(lambda: gimbal.seen == ["look_at"], 10, "the RAL's point")
        control.publish(Entrada(slot_entrada_datos=2))
        wait_until(lambda: gimbal.routes == {"datos": 2}, 10, "routed to vision")
        time.sleep(0.5)
        vision.publish(Point(name="vision1"))
        wait_until(lambda: gimbal.seen == ["look_at", "vision1"], 10, "vision's point")
        control.publish(Entrada(slot_entrada_datos=1))  # back: the RAL publishes nothing new
        wait_until(lambda: gimbal.seen == ["look_at", "vision1", "look_at"], 10, "the RAL's point again")
        control.publish(Entrada(slot_entrada_datos=2))  # vision keeps no value: nothing until it publishes
        wait_until(lambda: gimbal.routes == {"datos": 2}, 10, "routed to vision again")
        time.sleep(1.0)
        assert gimbal.seen == ["look_at", "vision1", "look_at"]
        vision.publish(Point(name="vision2"))
        wait_until(lambda: gimbal.seen[-1] == "vision2", 10, "vision's next point")
        ral.publish(Point(name="later"))  # the RAL's new point is not read while vision is routed
        control.publish(Entrada(slot_entrada_datos=1))
        wait_until(lambda: gimbal.seen[-1] == "later", 10, "the RAL's newest point, not an older one")
        time.sleep(0.5)
        assert gimbal.seen == ["look_at", "vision1", "look_at", "vision2", "later"]
    finally:
        gimbal.request_stop()
        thread.join(10)
        for pub in (ral, vision, control):
            pub.close()
