"""The fleet mesh's identities in the robot router's policy (bbcs/acl.py): a peer robot's router writes only its own
robot's keys, a hub gets the ground stations' rights and other robots' writes, neither writes this robot's keys.

The policy is evaluated here the way Zenoh's ingress check reads it: an identity may send a message on a key when a
rule of one of its policies allows that message on a key expression including the key, and no deny rule of its
policies intersects it (a deny wins). The system test (tests/system/test_secure_mesh.py) checks it on real routers.
"""

from __future__ import annotations

import json
from typing import Any

import pytest
import zenoh

from bbcs import acl, keys
from bbcs.contracts.dsp import commands_slot
from bbcs.contracts.sync import clock_key, sync_key
from bbcs.contracts.world import world_request_key

ROBOT = "uav1"


def _policy(**kw: Any) -> dict[str, Any]:
    return acl.router_config(listen=["tls/127.0.0.1:1"], ca="c", cert="r", key="k", robot=ROBOT, gcs=["gcs"],
                             modules=["dsp", "path_follower", "vision"], **kw)


def may(cfg: dict[str, Any], cn: str, message: str, key: str) -> bool:
    """Whether ``cn`` may send ``message`` on ``key`` into this router (ingress), by the rules as Zenoh reads them."""
    ac = cfg["access_control"]
    subjects = {s["id"] for s in ac["subjects"] if cn in s["cert_common_names"]}
    rules = {r["id"]: r for r in ac["rules"]}
    mine = [rules[rid] for p in ac["policies"] if subjects & set(p["subjects"]) for rid in p["rules"]]
    mine = [r for r in mine if "ingress" in r["flows"] and message in r["messages"]]
    ke = zenoh.KeyExpr(key)
    if any(r["permission"] == "deny" and any(zenoh.KeyExpr(k).intersects(ke) for k in r["key_exprs"]) for r in mine):
        return False
    return any(r["permission"] == "allow" and any(zenoh.KeyExpr(k).includes(ke) for k in r["key_exprs"])
               for r in mine)


def robot_writes(robot: str) -> list[tuple[str, str]]:
    """(message, key) a robot's modules, RAL and manager send: slots, GRI/MRI, @adv caches, schemas, tokens."""
    slot = keys.slot_key(robot, "dsp", "telemetry")
    return [
        ("put", slot), ("put", keys.slot_key(robot, "dsp", commands_slot("path_follower"))),
        ("put", keys.route_ack_key(robot, "dsp")), ("put", keys.heartbeat_key(robot, "dsp")),
        ("put", keys.ral_key(robot, "state")), ("put", keys.fleet_state_key(robot)),
        ("put", keys.manager_key(robot, "state")),
        ("reply", f"{slot}/@adv/pub/abc/1/2"), ("declare_queryable", f"{slot}/@adv/pub/abc/1/2"),
        ("liveliness_token", f"{slot}/@adv/pub/abc/1/2"), ("reply", f"{keys.ral_key(robot, 'fleet')}/@adv/pub/a/1"),
        ("declare_queryable", keys.schema_key(robot, "dsp")), ("declare_queryable", clock_key(robot)),
        ("declare_queryable", keys.ral_key(robot, "task")),
        ("declare_queryable", keys.schema_key_of(keys.ral_key(robot))),
        ("liveliness_token", keys.alive_key(robot, "dsp")),
    ]


def ground_station(robot: str) -> list[tuple[str, str]]:
    """What only a ground station sends: fleet tasks, link tokens, and the command queries on ``robot``."""
    return [("put", keys.fleet_task_key("t1")), ("put", keys.gcs_key("gcs")),
            ("liveliness_token", keys.gcs_key("gcs")), ("query", keys.ral_key(robot, "task")),
            ("query", keys.manager_key(robot, "route")), ("query", world_request_key(robot)),
            ("query", sync_key(robot))]


def test_a_peer_robot_router_writes_only_its_own_robot() -> None:
    cfg = _policy(mesh_robots=["uav2", "uav3"])
    peer = acl.mesh_router_cn("uav2")
    assert peer == "router-uav2"
    for message, key in robot_writes("uav2"):
        assert may(cfg, peer, message, key), (message, key)
    for message, key in robot_writes(ROBOT) + robot_writes("uav3") + ground_station(ROBOT):
        assert not may(cfg, peer, message, key), (message, key)
    # observing like everyone: subscribe, read-only queries, history, its advanced subscribers' tokens
    assert may(cfg, peer, "declare_subscriber", keys.ral_key(ROBOT, "state"))
    assert may(cfg, peer, "query", clock_key(ROBOT))
    assert may(cfg, peer, "query", f"{keys.fleet_state_key(ROBOT)}/@adv/**")
    assert may(cfg, peer, "liveliness_token", f"{keys.fleet_state_key(ROBOT)}/@adv/sub/x/1")


def test_a_hub_has_ground_station_rights_and_other_robots_writes_never_this_robots() -> None:
    cfg = _policy(hubs=["hub"])
    for message, key in ground_station(ROBOT) + robot_writes("uav2") + robot_writes("uav9"):
        assert may(cfg, "hub", message, key), (message, key)
    for message, key in robot_writes(ROBOT):
        assert not may(cfg, "hub", message, key), (message, key)
    # a ground station's advanced subscriber on this robot's state, forwarded by the hub, keeps its presence token
    assert may(cfg, "hub", "liveliness_token", f"{keys.ral_key(ROBOT, 'state')}/@adv/sub/x/1")


def test_mesh_identities_change_nothing_for_the_robots_own_identities() -> None:
    plain, meshed = _policy(), _policy(mesh_robots=["uav2"], hubs=["hub"])
    for cn in ("gcs", "ral", "manager", "dsp", "vision"):
        for message, key in robot_writes(ROBOT) + ground_station(ROBOT) + robot_writes("uav2"):
            assert may(plain, cn, message, key) == may(meshed, cn, message, key), (cn, message, key)
    assert may(meshed, "gcs", "query", keys.ral_key(ROBOT, "task"))
    assert not may(meshed, "vision", "put", keys.slot_key("uav2", "dsp", "telemetry"))
    # a router that dials its peers presents its own certificate on those links
    tls = meshed["transport"]["link"]["tls"]
    assert (tls["connect_certificate"], tls["connect_private_key"]) == ("r", "k")
    zenoh.Config.from_json5(json.dumps(meshed))


def test_the_hub_routers_own_policy() -> None:
    cfg = acl.hub_config(listen=["tls/127.0.0.1:1"], ca="c", cert="h", key="k", gcs=["gcs"], robots=["uav1", "uav2"])
    for robot in ("uav1", "uav2"):
        assert all(may(cfg, "gcs", m, k) for m, k in ground_station(robot))
        assert all(may(cfg, acl.mesh_router_cn(robot), m, k) for m, k in robot_writes(robot))
    assert not any(may(cfg, "router-uav1", m, k) for m, k in robot_writes("uav2") + ground_station("uav2"))
    assert not any(may(cfg, "gcs", m, k) for m, k in robot_writes("uav1"))
    assert not any(may(cfg, "router-uav9", m, k) for m, k in robot_writes("uav9"))  # an unlisted robot: nothing
    zenoh.Config.from_json5(json.dumps(cfg))


@pytest.mark.parametrize(("kw", "match"), [
    ({"mesh_robots": [ROBOT]}, "its own mesh peer"),
    ({"mesh_robots": ["uav/2"]}, "mesh identity"),
    ({"hubs": ["bad name"]}, "mesh identity"),
])
def test_bad_mesh_identities_are_refused(kw: dict[str, Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        _policy(**kw)
    with pytest.raises(ValueError, match="robot name"):
        acl.router_config(listen=[], ca="c", cert="r", key="k", gcs=["gcs"], modules=[], hubs=["hub"])
