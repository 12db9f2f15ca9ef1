"""The module's one event loop, driven without a router (bbcs.testing.ModuleDriver), and error codes taken from
the failing field's declaration."""

from __future__ import annotations

from typing import Annotated

import msgspec
import pytest

from bbcs.codec import violates_constraint
from bbcs.conf import ConfError
from bbcs.errors import EXIT_CONFIG, BusErrorCode, SlotError
from bbcs.module import Control, Module
from bbcs.routing import SlotRef, SlotTable
from bbcs.slots import InputSlot, Kind, OutputSlot
from bbcs.testing import Input, ModuleDriver, RouteChange, Stop, Tick

Lat = Annotated[float, msgspec.Meta(ge=-90.0, le=90.0)]


class Point(msgspec.Struct, frozen=True, kw_only=True):
    lat: Lat
    name: Annotated[str, msgspec.Meta(max_length=8)] = "p"


class Path_(msgspec.Struct, frozen=True, kw_only=True):
    points: list[Point]
    speed: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 1.0
    note: str | None = None


class Err(msgspec.Struct, frozen=True):
    code: int


class Ctl(msgspec.Struct, frozen=True, kw_only=True):
    src: int


class Doubler(Module):
    name = "doubler"
    slots = (InputSlot("path", Path_, kind=Kind.STREAM), InputSlot("extra", Path_),
             OutputSlot("out", Point, kind=Kind.STREAM), OutputSlot("error", Err, kind=Kind.STREAM))
    control = Control(Ctl, {"src": "extra"})
    error_slot = "error"
    field_codes = {("path", "speed"): 120}

    def on_start(self) -> None:
        self.events: list[str] = ["start"]

    def on_path(self, msg: Path_) -> None:
        self.events.append("path")
        for p in msg.points:
            self.publish("out", Point(lat=p.lat / 2))

    def on_extra(self, msg: Path_) -> None:
        if msg.note == "boom":
            raise RuntimeError("handler bug")
        self.events.append("extra")

    def on_tick(self) -> None:
        self.events.append("tick")

    def on_route_change(self, routes: dict[str, int]) -> None:
        self.events.append(f"route {routes}")

    def on_stop(self) -> None:
        self.events.append("stop")


TABLE = SlotTable(robot="r1", slots={
    7: SlotRef(module="other", slot="path", type=f"{__name__}:Path_"),
    8: SlotRef(module="other", slot="pt", type=f"{__name__}:Point"),
})


def test_inputs_ticks_routes_and_stop_are_handled_in_order() -> None:
    d = ModuleDriver(Doubler, robot="r1", slot_table=TABLE)
    d.feed(Input("path", Path_(points=[Point(lat=10.0), Point(lat=-4.0)])), Tick(),
           RouteChange({"extra": 7}), Input("extra", Path_(points=[])), Stop())
    m = d.module
    assert m.events == ["start", "path", "tick", "route {'extra': 7}", "extra", "stop"]
    assert d.published["out"] == [Point(lat=5.0), Point(lat=-2.0)]
    assert [(a.accepted, a.routes) for a in d.acks] == [(True, {"extra": 7})]
    assert d.errors == [] and m.stopping


def test_out_of_range_input_is_rejected_with_the_fields_code_and_never_handled() -> None:
    d = ModuleDriver(Doubler, robot="r1").start()
    d.feed(Input("path", Path_(points=[Point(lat=1.0)], speed=99.0)),        # field_codes entry
           Input("path", Path_(points=[Point(lat=1.0), Point(lat=91.0)])),   # nested range → OUT_OF_RANGE
           Input("path", Path_(points=[Point(lat=1.0, name="much too long")])),
           Input("path", b"\x93not msgpack of a Path_"),                      # malformed
           Input("path", msgspec.msgpack.encode({"points": [{"lat": "north"}]})))  # wrong type → malformed
    assert d.errors == [120, BusErrorCode.OUT_OF_RANGE, BusErrorCode.OUT_OF_RANGE, BusErrorCode.MALFORMED,
                        BusErrorCode.MALFORMED]
    assert d.published["out"] == [] and d.module.events == ["start"]
    assert d.module.rejected == 5


def test_a_failing_handler_is_reported_and_the_loop_goes_on() -> None:
    d = ModuleDriver(Doubler, robot="r1").start()
    d.feed(Input("extra", Path_(points=[], note="boom")), Input("extra", Path_(points=[])))
    assert d.errors == [BusErrorCode.HANDLER_FAILED]
    assert d.module.events == ["start", "extra"]


def test_a_route_to_a_slot_of_another_type_is_refused_and_the_old_route_kept() -> None:
    d = ModuleDriver(Doubler, robot="r1", slot_table=TABLE).start()
    d.feed(RouteChange({"extra": 7}), RouteChange({"extra": 8}), RouteChange({"extra": 99}))
    assert [a.accepted for a in d.acks] == [True, False, False]
    assert d.module.routes == {"extra": 7}
    assert d.errors == [BusErrorCode.ROUTE_TYPE_MISMATCH, BusErrorCode.ROUTE_UNKNOWN_SLOT]


def test_feeding_an_unknown_slot_is_an_error() -> None:
    with ModuleDriver(Doubler, robot="r1") as d, pytest.raises(SlotError):
        d.feed(Input("nope", Point(lat=0.0)))


@pytest.mark.parametrize(("value", "path", "expected"), [
    (Path_(points=[], speed=11.0), "$.speed", True),
    (Path_(points=[Point(lat=0.0), Point(lat=-95.0)]), "$.points[1].lat", True),
    (Path_(points=[Point(lat=0.0, name="123456789")]), "$.points[0].name", True),
    ({"points": [], "speed": "fast"}, "$.speed", False),
    ({"points": [{"lat": True}]}, "$.points[0].lat", False),
    ({"points": [], "note": 3}, "$.note", False),
    ({"points": 5}, "$.points", False),
])
def test_a_constraint_violation_is_told_from_a_malformed_value(value: object, path: str, expected: bool) -> None:
    payload = msgspec.msgpack.encode(value)
    with pytest.raises(msgspec.ValidationError):
        msgspec.msgpack.decode(payload, type=Path_)
    assert violates_constraint(Path_, path, payload) is expected


class BadConf(Module):
    name = "badconf"

    def __init__(self, context) -> None:  # type: ignore[no-untyped-def]
        super().__init__(context)
        raise ConfError("robot.conf:3: MAX_SPEED: expected a number, got 'fast'")


def test_main_returns_exit_config_on_a_configuration_error() -> None:
    assert EXIT_CONFIG == 78
    assert BadConf.main(["--robot", "r1", "--connect", "tcp/127.0.0.1:9"]) == EXIT_CONFIG
