import pytest

from bbcs.codec import resolve_type, type_name
from bbcs.errors import BusErrorCode, RouteError
from bbcs.routing import IGNORE, SlotRef, SlotTable

T_A = "tests.bbcs.probe_module:ProbeMsg"


def table() -> SlotTable:
    return SlotTable(robot="uav1", slots={
        1: SlotRef(module="gcs", slot="datos", type=T_A),
        2: SlotRef(module="vision", slot="target", type="x.y:Other"),
        3: SlotRef(module="gcs", slot="datos", type=T_A, robot="uav2"),
    })


def test_resolve_ok_and_ignore():
    assert table().resolve(1, T_A) == "cromat/uav1/gcs/datos"
    assert table().resolve(3, T_A) == "cromat/uav2/gcs/datos"
    assert table().resolve(IGNORE, T_A) is None


def test_unknown_number_refused_with_code():
    with pytest.raises(RouteError) as err:
        table().resolve(9, T_A)
    assert err.value.code == BusErrorCode.ROUTE_UNKNOWN_SLOT
    assert "slot 9" in str(err.value)


def test_type_mismatch_refused_with_code():
    with pytest.raises(RouteError) as err:
        table().resolve(2, T_A)
    assert err.value.code == BusErrorCode.ROUTE_TYPE_MISMATCH
    assert "x.y:Other" in str(err.value)


def test_type_names_resolve_back():
    from bbcs.routing import RouteAck
    assert resolve_type(type_name(RouteAck)) is RouteAck
    for bad in ["nocolon", "no_such_module_xyz:X", "bbcs.routing:Nope", "bbcs.routing:IGNORE"]:
        with pytest.raises(LookupError):
            resolve_type(bad)


def test_context_from_env_with_extra_arguments(monkeypatch):
    from bbcs.context import CONTEXT_ENV, ModuleContext, encode_context, load_context

    base = ModuleContext(robot="uav1", module="vision", params={"rate": "10"}, routes={"datos": 3})
    monkeypatch.setenv(CONTEXT_ENV, encode_context(base))
    assert load_context(None, "x", "vision") == base
    merged = load_context(["--param", "noise=4", "--route", "datos=5"], "x", "vision")
    assert merged.params == {"rate": "10", "noise": "4"} and merged.routes == {"datos": 5}
    assert merged.robot == "uav1" and merged.module == "vision"


def test_context_from_arguments_alone(monkeypatch, tmp_path):
    import msgspec

    from bbcs.context import CONTEXT_ENV, load_context

    monkeypatch.delenv(CONTEXT_ENV, raising=False)
    table = tmp_path / "t.json"
    table.write_bytes(msgspec.json.encode(table_obj := SlotTable(robot="r", slots={1: SlotRef(module="a", slot="b",
                                                                                          type=T_A)})))
    ctx = load_context(["--robot", "r", "--name", "m", "--connect", "tcp/127.0.0.1:1", "--slot-table", str(table),
                        "--route", "x=1", "--param", "k=v"], "x", "dflt")
    assert (ctx.robot, ctx.module, ctx.bus.connect, ctx.routes, ctx.params) == (
        "r", "m", ["tcp/127.0.0.1:1"], {"x": 1}, {"k": "v"})
    assert ctx.slot_table == table_obj
