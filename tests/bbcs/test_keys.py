import pytest

from bbcs import keys
from bbcs.errors import InvalidNameError


def test_slot_key_round_trip():
    key = keys.slot_key("uav1", "pan_tilt", "datos")
    assert key == "cromat/uav1/pan_tilt/datos"
    assert keys.parse_slot_key(key) == ("uav1", "pan_tilt", "datos")


def test_namespaces():
    assert keys.alive_key("uav1", "dsp") == "cromat/uav1/@alive/dsp"
    assert keys.parse_alive_key("cromat/uav1/@alive/dsp") == ("uav1", "dsp")
    assert keys.alive_pattern() == "cromat/*/@alive/*"
    assert keys.manager_key("uav1", "routes") == "cromat/uav1/@manager/routes"
    assert keys.ral_key("*", "state") == "cromat/*/@ral/state"
    assert keys.schema_key("uav1", "dsp") == "cromat/uav1/dsp/@schema"


@pytest.mark.parametrize("bad", ["", "a*b", "a$", "a/b", "a#", "why?", "@ral", "has space", ".hidden", "x" * 65])
def test_bad_names_refused(bad):
    with pytest.raises(InvalidNameError):
        keys.slot_key("uav1", bad, "datos")
    with pytest.raises(InvalidNameError):
        keys.slot_key(bad, "m", "datos")


@pytest.mark.parametrize("key", ["cromat/uav1/m", "other/uav1/m/s", "cromat/uav1/m/s/extra", "cromat/*/m/s"])
def test_parse_rejects_non_slot_keys(key):
    with pytest.raises(InvalidNameError):
        keys.parse_slot_key(key)


def test_patterns_take_wildcards_chunk_by_chunk():
    assert keys.slot_pattern() == "cromat/*/*/*"
    assert keys.slot_pattern("uav1", "dsp", "commands") == "cromat/uav1/dsp/commands"
    assert keys.schema_pattern("uav1", "ral") == "cromat/uav1/ral/@schema"
    assert keys.route_ack_pattern() == "cromat/*/*/@route"
    assert keys.heartbeat_pattern("uav1", "dsp") == "cromat/uav1/dsp/@heartbeat"
    assert keys.alive_pattern("uav1", "ral") == "cromat/uav1/@alive/ral"
    assert keys.manager_pattern("uav1") == "cromat/uav1/@manager/**"
    assert keys.ral_pattern() == "cromat/*/@ral/**"
    assert keys.gcs_key("*") == "cromat/@gcs/*"
    assert keys.gcs_pattern() == "cromat/@gcs/**"
    assert keys.adv_pattern(keys.slot_pattern()) == "cromat/*/*/*/@adv/**"


@pytest.mark.parametrize("bad", ["**", "a*", "@x", ""])
def test_patterns_refuse_anything_but_names_and_star(bad):
    with pytest.raises(InvalidNameError):
        keys.slot_pattern("uav1", bad)
    with pytest.raises(InvalidNameError):
        keys.alive_pattern(bad)
