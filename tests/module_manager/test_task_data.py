"""The four-hop command path's decision (module_manager/task_data.py): a task's data ride inside its mode only
where the routes take each datum to an input the mode has a field for, and all or none of them."""

from __future__ import annotations

from module_manager.task_data import carry, kept

MODE_MODULE = {"pf_mode": "path_follower", "pt_mode": "pan_tilt"}
FIELDS = {"pf_mode": frozenset({"modo", "velocidad", "heading", "datos"}), "pt_mode": frozenset({"modo", "datos"})}
ROUTES = {("path_follower", "velocidad"): 13, ("path_follower", "datos"): 11, ("path_follower", "heading"): -1,
          ("pan_tilt", "datos"): 10}
SPEED, PATH = {"speed": 3.0}, {"n_points": 1, "puntos": [{"latitud": 37.0, "longitud": -6.0, "altura": 30.0}]}


def test_each_datum_rides_in_the_mode_field_of_the_input_its_slot_is_routed_to() -> None:
    got = carry({13: SPEED, 11: PATH}, ["pf_mode"], MODE_MODULE, FIELDS, ROUTES)
    assert got == {"pf_mode": {"velocidad": SPEED, "datos": PATH}}
    assert carry({10: {"ref_pan": 30.0}}, ["pt_mode"], MODE_MODULE, FIELDS, ROUTES) == {
        "pt_mode": {"datos": {"ref_pan": 30.0}}}


def test_a_task_without_data_carries_nothing() -> None:
    assert carry({}, ["pf_mode"], MODE_MODULE, FIELDS, ROUTES) == {}


def test_all_or_none_when_one_datum_reaches_no_carrying_input() -> None:
    """Speed routed elsewhere (a relay): neither is carried, so the RAL keeps the speed ahead of the path."""
    routes = {**ROUTES, ("path_follower", "velocidad"): 99}
    assert carry({13: SPEED, 11: PATH}, ["pf_mode"], MODE_MODULE, FIELDS, routes) is None


def test_no_datum_is_carried_by_a_mode_the_task_does_not_set_or_without_the_field() -> None:
    assert carry({10: {"ref_pan": 30.0}}, ["pf_mode"], MODE_MODULE, FIELDS, ROUTES) is None, "not the task's mode"
    narrow = {**FIELDS, "pt_mode": frozenset({"modo"})}
    assert carry({10: {"ref_pan": 30.0}}, ["pt_mode"], MODE_MODULE, narrow, ROUTES) is None, "no field for it"


def test_the_kept_value_drops_stream_data_and_keeps_state_data() -> None:
    value = {"modo": 0, "velocidad": SPEED, "datos": PATH}
    assert kept(value, frozenset({"datos"})) == {"modo": 0, "velocidad": SPEED}
    assert kept({"modo": 0, "datos": None}, frozenset({"datos"})) == {"modo": 0, "datos": None}
    assert kept(None, frozenset({"datos"})) is None
