"""A route switch handled from the loop's queue, through a real router: the switch drains what was queued behind it
(everything up to the switch point is handled first), and the loop then goes straight back to its timers.

Found in lockstep flights (tests/system/test_gcs_mission.py, one run in fifteen beside busy processes): an abort
restores the pan & tilt's DATOS route while other work is queued; the loop, still counting the items it had seen
queued before the switch drained them, blocked on the empty queue. The pan & tilt then neither ticked nor
answered the simulator's step, and the simulation stood still until the next datum happened to arrive."""

from __future__ import annotations

from collections.abc import Iterator

import msgspec
import pytest

from bbcs.context import ModuleContext
from bbcs.module import Control, Module
from bbcs.routing import SlotRef, SlotTable
from bbcs.session import local_client
from bbcs.slots import InputSlot, Kind
from bbcs.testing import RouteChange, running, wait_alive, wait_until


class Angle(msgspec.Struct, frozen=True, kw_only=True):
    deg: float


class Ctl(msgspec.Struct, frozen=True, kw_only=True):
    datos: int


TABLE = SlotTable(robot="r1", slots={
    7: SlotRef(module="gcs", slot="angle", type=f"{__name__}:Angle"),
    8: SlotRef(module="vision", slot="angle", type=f"{__name__}:Angle"),
})


class Follower(Module):
    """One routed input (callback-delivered, like the pan & tilt's DATOS) and a tick."""

    name = "follower"
    slots = (InputSlot("datos", Angle, kind=Kind.STATE),)
    control = Control(Ctl, {"datos": "datos"})
    tick_period = 0.05

    def on_start(self) -> None:
        self.ticks = 0
        self.order: list[str] = []

    def on_datos(self, msg: Angle) -> None:
        self.order.append(f"datos {msg.deg:g}")

    def on_tick(self) -> None:
        self.ticks += 1

    def on_route_change(self, routes: dict[str, int]) -> None:
        self.order.append(f"route {routes['datos']}")


@pytest.fixture
def follower(router: int) -> Iterator[Follower]:
    with running(Follower(ModuleContext(robot="r1", module="follower", bus=local_client(router), slot_table=TABLE,
                                        routes={"datos": 7}))) as mod:
        yield mod


def test_a_switch_that_drains_the_queue_leaves_the_loop_free(follower: Follower, sessions) -> None:
    mod = follower
    wait_alive(sessions(), "r1", "follower")
    wait_until(lambda: mod.ticks >= 2, 10, "the first ticks")

    def queue_a_switch_then_more_work() -> None:
        # on the loop: the switch and one more call are queued at once, as an abort's route restore and the
        # next input are; the switch's drain takes the call before the loop's own pass reaches it
        mod._bbcs_queue.put((None, RouteChange({"datos": 8})))
        mod._bbcs_queue.put((None, lambda: mod.order.append("queued behind the switch")))

    mod.call_soon(queue_a_switch_then_more_work)
    wait_until(lambda: "route 8" in mod.order, 10, "the switch")
    assert mod.order == ["queued behind the switch", "route 8"], "the switch point is after what was queued"
    assert mod.routes == {"datos": 8}
    ticks = mod.ticks
    # nothing more is queued or published: the loop must still run its timers
    wait_until(lambda: mod.ticks >= ticks + 5, 5, "ticks after the switch (the loop blocked on an empty queue)")
