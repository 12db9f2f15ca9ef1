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
