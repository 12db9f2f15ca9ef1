"""Module declarations are checked when the class is defined, before any process starts."""

import msgspec
import pytest

from bbcs.errors import InvalidNameError, SlotError
from bbcs.module import Control, Module
from bbcs.slots import InputSlot, Kind, OutputSlot, Safety


class Msg(msgspec.Struct, frozen=True):
    x: int


class Err(msgspec.Struct, frozen=True):
    error_x: int


class Ctl(msgspec.Struct, frozen=True):
    slot_entrada_a: int


def test_missing_handler_refused():
    with pytest.raises(SlotError, match="on_a"):
        type("M", (Module,), {"slots": (InputSlot("a", Msg),)})


def test_duplicate_slot_refused():
    with pytest.raises(SlotError, match="twice"):
        type("M", (Module,), {"slots": (OutputSlot("a", Msg), OutputSlot("a", Msg))})


def test_error_struct_must_have_one_field():
    with pytest.raises(SlotError, match="not an output slot"):
        type("M", (Module,), {"slots": (OutputSlot("error", Msg),), "error_slot": "nope"})
    two = msgspec.defstruct("Two", [("a", int), ("b", int)])
    with pytest.raises(SlotError, match="exactly one int field"):
        type("M", (Module,), {"slots": (OutputSlot("error", two),), "error_slot": "error"})


def test_control_must_route_declared_unpeered_inputs():
    with pytest.raises(SlotError, match="no field"):
        type("M", (Module,), {"slots": (InputSlot("a", Msg),), "on_a": lambda s, v: None,
                              "control": Control(Ctl, {"nope": "a"})})
    with pytest.raises(SlotError, match="unknown input"):
        type("M", (Module,), {"slots": (), "control": Control(Ctl, {"slot_entrada_a": "a"})})
    with pytest.raises(SlotError, match="fixed peer"):
        type("M", (Module,), {"slots": (InputSlot("a", Msg, peer="dsp"),), "on_a": lambda s, v: None,
                              "control": Control(Ctl, {"slot_entrada_a": "a"})})


def test_stream_cannot_be_unsafe_and_peers_resolve():
    with pytest.raises(SlotError, match="always safe"):
        InputSlot("a", Msg, kind=Kind.STREAM, safety=Safety.UNSAFE)
    assert InputSlot("telemetry", Msg, peer="dsp").key("uav1", "telemetry") == "cromat/uav1/dsp/telemetry"
    assert OutputSlot("commands", Msg, peer="dsp").key("uav1", "pan_tilt") == "cromat/uav1/dsp/commands"
    assert OutputSlot("error", Err).key("uav1", "pan_tilt") == "cromat/uav1/pan_tilt/error"
    assert InputSlot("dsp_telemetry", Msg, peer="dsp/telemetry").key("uav1", "x") == "cromat/uav1/dsp/telemetry"
    with pytest.raises(InvalidNameError):
        InputSlot("a", Msg, peer="dsp/te*")


def test_a_valid_declaration_lists_its_slots():
    cls = type("M", (Module,), {"slots": (InputSlot("a", Msg), OutputSlot("error", Err)), "error_slot": "error",
                                "on_a": lambda s, v: None, "control": Control(Ctl, {"slot_entrada_a": "a"})})
    assert set(cls._inputs) == {"a", "control_entrada"} and set(cls._outputs) == {"error"}
    assert cls._routed == frozenset({"a"}) and cls._error_field == "error_x"
