"""The robot router's access policy, generated from the identities it must know: write rights follow ownership.

Zenoh enforces access control on the links that arrive at the router that configures it, so this policy
goes on the robot's router (``cromat router --config FILE``). Identities are certificate common names under
mutual TLS (the router reads the CN of the certificate the TLS handshake verified; nothing in a message counts).
Default deny; then:

* every authenticated identity may observe: declare subscribers, liveliness subscribers and queries, ask
  late-joiner history (``query`` on ``…/@adv/**``), read-only queries (schemas, MRI lists), receive everything;
* a key has one writer. Writing is ``put``/``delete``, and also ``reply`` (a reply to a history or get query is
  a value the querier will use) and ``declare_queryable``/``liveliness_token`` on ``…/@adv/**`` (an advanced
  publisher's cache and presence). All of them are granted only to the key's owner:

  - a module: its own slots ``cromat/<robot>/<name>/*`` (``@route``, ``@heartbeat``, ``@schema`` included) except
    its CONTROL_ENTRADA, which an explicit **deny** keeps for the manager; a DSP sender also its own command key
    ``cromat/<robot>/dsp/commands_<name>`` (bbcs.contracts.dsp: one key per sender, so the router can tell
    senders apart, and the DSP checks the command classes that key's sender owns);
  - the manager: its mode slots ``cromat/<robot>/manager/*``, every module's CONTROL_ENTRADA, ``@manager/**``
    and ``@manager/@schema``;
  - the RAL: its slots, the GRI keys ``@ral/**`` and ``@ral/@schema``, and the requests it makes of modules on
    their own keys (:data:`RAL_REQUESTS`: the trajectory generator's ``request``, the path follower's ``refs``),
    which the key's module may also write and no one else;
  - a ground station: only ``cromat/@gcs/**`` (its link tokens and heartbeats) and fleet tasks
    ``cromat/@fleet/task/*``; it may query ``@ral/task`` (tasks), ``@manager/route`` (route swaps),
    ``@ral/world_request`` (world edits) and ``@ral/sync`` (synchronised starts), which no other identity may.

The fleet mesh (docs/fleet.md): Zenoh's policy sees only the identity of the link a message arrives on, never the
original sender, so trust follows the link. Two identities of other routers:

* a **peer robot's router** (CN ``router-<robot>``, :func:`mesh_router_cn`) may write only what its own robot
  owns (:func:`robot_keys`: every key under ``cromat/<that robot>/``), and observe like everyone;
* a **hub** (ground) router forwards ground stations and other robots: it gets a ground station's rights and the
  write rights of every robot but this one (it is as trusted as everything behind it).

Neither may write this robot's keys. :func:`hub_config` is the hub router's own policy.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

from bbcs import keys
from bbcs.contracts.dsp import COMMAND_RIGHTS, commands_slot
from bbcs.contracts.dsp import MODULE as DSP_MODULE
from bbcs.contracts.params import module_params_pattern
from bbcs.contracts.sync import clock_key, sync_key
from bbcs.contracts.world import world_model_key, world_request_key

OLD_COMMANDS_SLOT = "commands"
"""The DSP's old shared command mailbox (``dsp/commands``): gone; nobody may write it, not even the DSP."""

ALL_MESSAGES = [
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "reply",
    "declare_queryable",
    "liveliness_token",
    "liveliness_query",
    "declare_liveliness_subscriber",
]


WRITE = ["put", "delete", "reply"]
"""What makes a value others will use: publications and answers to queries (history included)."""
SERVE = ["declare_queryable", "liveliness_token"]
"""What makes an identity a source others will ask: a queryable (an advanced publisher's cache) or a token."""
OBSERVE = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "query"]


def _adv(keys_: list[str]) -> list[str]:
    """The advanced pub/sub keys of ``keys_``: ``**`` never matches the verbatim ``@adv`` chunk."""
    return [keys.adv_pattern(k) for k in keys_]


def _adv_sub(adv_keys: list[str]) -> list[str]:
    """``…/@adv/sub/**`` of each ``…/@adv/**``: where an advanced subscriber declares its presence token."""
    return [k.removesuffix("/**") + "/sub/**" for k in adv_keys]


def _read_keys(r: str = "*") -> list[str]:
    """Keys anyone authenticated may observe, for every robot (a GCS lists robots with ``cromat/*/...``)."""
    return [
        keys.slot_pattern(r),
        keys.schema_pattern(r),
        keys.route_ack_pattern(r),
        keys.heartbeat_pattern(r),
        keys.alive_pattern(r),
        keys.manager_pattern(r),
        keys.ral_pattern(r),
        keys.gcs_pattern(),
        *(keys.schema_key_of(k(r)) for k in (keys.ral_key, keys.manager_key)),
        keys.fleet_task_key("*"),
    ]


def _adv_keys(r: str = "*") -> list[str]:
    return _adv([keys.slot_pattern(r), keys.route_ack_pattern(r), keys.heartbeat_pattern(r),
                 keys.manager_child_pattern(r), keys.ral_child_pattern(r)])


SERVICE_SCHEMAS = [keys.schema_key_of(keys.ral_key("*")), keys.schema_key_of(keys.manager_key("*"))]
"""``cromat/*/@ral/@schema`` and ``cromat/*/@manager/@schema``: named apart, because neither ``*`` nor ``**``
matches a verbatim ``@`` chunk (``@ral/**`` does not cover ``@ral/@schema``)."""

READ_QUERIES = [keys.schema_pattern("*"), *SERVICE_SCHEMAS,
                *(keys.manager_key("*", q) for q in ("modules", "routes", "tasks")),
                clock_key("*"), world_model_key("*")]
"""Read-only queries every identity may make, on every robot: schemas, the MRI's lists, the RAL's clock probe
(docs/sync.md) and its copy of the shared world model (docs/world.md)."""

def _gcs_commands(r: str) -> list[str]:
    """Queries that change a robot, the ground stations' only: tasks, route swaps, run-time parameters (``cromat
    param``: its list and get ride the same verb as its set), world edits, synchronised starts."""
    return [keys.ral_key(r, "task"), keys.manager_key(r, "route"), keys.manager_key(r, "param"), world_request_key(r),
            sync_key(r)]

RAL_REQUESTS = [("trajectory", "request"), ("path_follower", "refs")]
"""(module, slot): inputs read on the module's own key that the RAL writes (survey/orbit requests to the
trajectory generator, a bridge task's references to the path follower). Besides the module itself, only the RAL
may write them."""


SET_POINT_RATES_HZ = {"pan_tilt": 200.0}
"""DSP senders whose batches are set-points (the newest supersedes the rest), and the most batches a second the
router lets through on their command key (Zenoh's downsampling at its ingress, per link and so per identity): a
put within 5 ms of the last one passed is dropped. pan & tilt follows targets at the vision rate (10 Hz); a flood of
53-95 k/s queued on the DSP's link ahead of the abort (issue 32 item 1). Not the path follower's: a dropped waypoint
or abort batch is never acceptable."""


def _own(robot: str, name: str) -> list[str]:
    """A module's own keys: its slots, route acknowledgements, heartbeat, schema and its run-time parameter server
    (``<name>/@params``: named apart, ``*`` never matches an ``@`` chunk)."""
    own = [keys.slot_pattern(robot, name), keys.route_ack_pattern(robot, name), keys.heartbeat_pattern(robot, name)]
    return [*own, *_adv(own), keys.schema_pattern(robot, name), module_params_pattern(robot, name)]


MESH_ROUTER_PREFIX = "router-"


def mesh_router_cn(robot: str) -> str:
    """The certificate CN of ``robot``'s router on the fleet mesh (``router-uav2``)."""
    return MESH_ROUTER_PREFIX + keys.validate_name(robot, "robot name")


def robot_keys(r: str) -> list[str]:
    """Every key robot ``r`` (its modules, RAL and manager) writes or serves, ``@adv`` included: named chunk by
    chunk, because ``*``/``**`` never match a verbatim ``@`` chunk. ``r`` may be ``*`` (any robot)."""
    own = [keys.slot_pattern(r), keys.route_ack_pattern(r), keys.heartbeat_pattern(r)]
    services = [keys.manager_pattern(r), keys.ral_pattern(r)]
    return [*own, *_adv(own), keys.schema_pattern(r), module_params_pattern(r), *services,
            *_adv([keys.manager_child_pattern(r), keys.ral_child_pattern(r)]),
            *(keys.schema_key_of(k(r)) for k in (keys.ral_key, keys.manager_key))]


def _robot_write_rules(rid: str, r: str) -> list[dict[str, Any]]:
    """Robot ``r``'s writes, its servers and its presence tokens (``@alive``, advanced publishers')."""
    return [_rule(f"{rid}-write", WRITE + SERVE, robot_keys(r)),
            _rule(f"{rid}-token", ["liveliness_token"], [keys.alive_pattern(r)])]


def _rule(rid: str, messages: list[str], key_exprs: list[str], permission: str = "allow",
          flow: str = "ingress") -> dict[str, Any]:
    return {"id": rid, "permission": permission, "flows": [flow], "messages": list(messages),
            "key_exprs": list(dict.fromkeys(key_exprs))}


def router_config(
    *,
    listen: list[str],
    ca: str,
    cert: str,
    key: str,
    robot: str = "*",
    gcs: list[str],
    modules: list[str],
    ral: str = "ral",
    manager: str = "manager",
    identities: dict[str, str] | None = None,
    controls: dict[str, str] | None = None,
    dsp_senders: list[str] | None = None,
    mesh_robots: list[str] | None = None,
    hubs: list[str] | None = None,
    revoked: list[str] | None = None,
    write_rates: dict[str, float] | None = None,
) -> dict[str, Any]:
    """A complete Zenoh router config: ``tls/`` listeners with mTLS and the access policy above.

    ``mesh_robots`` are the robots whose routers link to this one directly (identity ``router-<name>``),
    ``hubs`` the CNs of hub (ground) routers. The router presents its own certificate on the links it dials
    (``[bus] peers``), so the other end's policy knows it by its CN as well.

    ``identities`` maps a module name (or ``ral``) to the certificate CN it presents when that differs from the
    name; the module's rights stay keyed by its name (its slots are ``cromat/<robot>/<name>/*``). ``controls``
    maps a module to its CONTROL_ENTRADA slot (default ``control_entrada``); ``dsp_senders`` are the modules
    given a DSP command key (default: those of ``modules`` that own command classes in bbcs.contracts.dsp).
    """
    cn = dict(identities or {})
    if robot != "*":
        keys.validate_name(robot, "robot name")
    for name in [*gcs, *modules, ral, manager, *(identities or {}).values()]:
        keys.validate_name(name, "identity")
    if not gcs:
        raise ValueError("at least one GCS identity is needed")
    peers, hub_cns = list(mesh_robots or []), list(hubs or [])
    for name in [*peers, *hub_cns]:
        keys.validate_name(name, "mesh identity")
    if robot != "*" and robot in peers:
        raise ValueError(f"robot {robot!r} cannot be its own mesh peer")
    if (peers or hub_cns) and robot == "*":
        raise ValueError("a router with mesh identities needs its robot name (its own keys stay its own)")
    control = {m: (controls or {}).get(m, "control_entrada") for m in modules}
    senders = [m for m in modules if m in COMMAND_RIGHTS] if dsp_senders is None else list(dsp_senders)
    r = robot
    control_keys = [keys.slot_pattern(r, m, slot) for m, slot in control.items()]
    rules: list[dict[str, Any]] = [
        _rule("observe", OBSERVE[:3], _read_keys() + _adv_keys()),
        _rule("history", ["query"], _adv_keys()),  # ask late-joiner history
        # an advanced subscriber's presence token (``…/@adv/sub/…``); a publisher's (``…/@adv/pub/…``) is the owner's
        _rule("history-sub", ["liveliness_token"], _adv_sub(_adv_keys())),
        _rule("read-queries", ["query"], READ_QUERIES),
        # a parameter change travels to a module and its answer back only as the manager asked (ingress rules)
        _rule("deliver", ALL_MESSAGES, _read_keys() + _adv_keys() + [module_params_pattern()], flow="egress"),
        _rule("gcs-command", ["query"], _gcs_commands(r)),
        _rule("gcs-link", ["put", "delete", "liveliness_token"], [keys.gcs_pattern(), keys.fleet_task_key("*")]),
        _rule("ral-write", WRITE + SERVE, [*_own(r, ral), keys.ral_pattern(r), *_adv([keys.ral_child_pattern(r)]),
                                           keys.schema_key_of(keys.ral_key(r))]),
        _rule("ral-requests", WRITE + SERVE, [k for m, slot in RAL_REQUESTS
                                              for k in (keys.slot_pattern(r, m, slot),
                                                        *_adv([keys.slot_pattern(r, m, slot)]))]),
        _rule("ral-token", ["liveliness_token"], [keys.alive_pattern(r, ral)]),
        _rule("ral-mri", ["query"], [keys.manager_pattern(r)]),
        _rule("manager-write", WRITE + SERVE, [
            *_own(r, manager), *control_keys, *_adv(control_keys), keys.manager_pattern(r),
            *_adv([keys.manager_child_pattern(r)]), keys.schema_key_of(keys.manager_key(r))]),
        _rule("manager-token", ["liveliness_token"], [keys.alive_pattern(r)]),
        # the manager alone hands a checked parameter change to a module (module_manager/params.py)
        _rule("manager-params", ["query"], [module_params_pattern(r, "*")]),
    ]
    subjects: list[dict[str, Any]] = [
        {"id": "gcs", "cert_common_names": list(gcs)},
        {"id": "ral", "cert_common_names": [cn.get("ral", ral)]},
        {"id": "manager", "cert_common_names": [manager]},
    ]
    policies: list[dict[str, Any]] = [
        {"id": "gcs", "subjects": ["gcs"], "rules": ["gcs-command", "gcs-link"]},
        {"id": "ral", "subjects": ["ral"], "rules": ["ral-write", "ral-token", "ral-mri", "ral-requests"]},
        {"id": "manager", "subjects": ["manager"], "rules": ["manager-write", "manager-token", "manager-params"]},
    ]
    for name in modules:
        own = _own(r, name)
        if name in senders:
            dsp_key = keys.slot_pattern(r, DSP_MODULE, commands_slot(name))
            own += [dsp_key, *_adv([dsp_key])]
        ctl = keys.slot_pattern(r, name, control[name])
        rules += [
            _rule(f"m-{name}-write", WRITE + SERVE, own),
            _rule(f"m-{name}-token", ["liveliness_token"], [keys.alive_pattern(r, name)]),
            # its own CONTROL_ENTRADA is the manager's to write: a deny wins over the allow on cromat/r/name/*
            _rule(f"m-{name}-no-control", [*WRITE, "declare_queryable"], [ctl, *_adv([ctl])], permission="deny"),
            # ... and presence as its publisher; its advanced subscriber's token (``@adv/sub``) stays allowed
            _rule(f"m-{name}-no-control-pub", ["liveliness_token"], [ctl, f"{ctl}/@adv/pub/**"], permission="deny"),
        ]
        own_rules = [f"m-{name}-write", f"m-{name}-token", f"m-{name}-no-control", f"m-{name}-no-control-pub"]
        if name == DSP_MODULE:  # its cromat/r/dsp/* covers every sender's command key: those stay the senders'
            mailboxes = [keys.slot_pattern(r, DSP_MODULE, s) for s in (*map(commands_slot, COMMAND_RIGHTS),
                                                                          OLD_COMMANDS_SLOT)]
            rules += [_rule(f"m-{name}-no-commands", [*WRITE, "declare_queryable"], [*mailboxes, *_adv(mailboxes)],
                            permission="deny"),
                      _rule(f"m-{name}-no-commands-pub", ["liveliness_token"],
                            [*mailboxes, *(f"{k}/@adv/pub/**" for k in mailboxes)], permission="deny")]
            own_rules += [f"m-{name}-no-commands", f"m-{name}-no-commands-pub"]
        subjects.append({"id": f"m-{name}", "cert_common_names": [cn.get(name, name)]})
        policies.append({"id": f"m-{name}", "subjects": [f"m-{name}"], "rules": own_rules})
    for name in peers:
        rules += _robot_write_rules(f"peer-{name}", name)
        subjects.append({"id": f"peer-{name}", "cert_common_names": [mesh_router_cn(name)]})
        policies.append({"id": f"peer-{name}", "subjects": [f"peer-{name}"],
                         "rules": [f"peer-{name}-write", f"peer-{name}-token"]})
    if hub_cns:
        # a hub forwards ground stations and every other robot; this robot's own keys stay its own (a deny wins)
        rules += [*_robot_write_rules("hub-robots", "*"),
                  _rule("hub-not-this-robot", [*WRITE, "declare_queryable"], robot_keys(r), permission="deny"),
                  # its publishers' presence; an advanced subscriber's token (``@adv/sub``) stays allowed
                  _rule("hub-not-this-robot-token", ["liveliness_token"],
                        [keys.alive_pattern(r), *(k.removesuffix("/**") + "/pub/**" for k in _adv_keys(r))],
                        permission="deny")]
        subjects.append({"id": "hub", "cert_common_names": hub_cns})
        policies.append({"id": "hub", "subjects": ["hub"],
                         "rules": ["gcs-command", "gcs-link", "hub-robots-write", "hub-robots-token",
                                   "hub-not-this-robot", "hub-not-this-robot-token"]})
    everyone = [s["id"] for s in subjects]
    policies.append({"id": "everyone", "subjects": everyone,
                     "rules": ["observe", "history", "history-sub", "read-queries", "deliver"]})
    _deny_revoked(rules, subjects, policies, revoked)
    config: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {
            "shared_memory": {"enabled": False},  # no payload around the policy through /dev/shm (bbcs/session.py)
            "link": {
                "protocols": ["tls"],
                "tls": {
                    "root_ca_certificate": ca,
                    "listen_certificate": cert,
                    "listen_private_key": key,
                    "enable_mtls": True,
                    "verify_name_on_connect": True,
                },
            }
        },
        "access_control": {
            "enabled": True,
            "default_permission": "deny",
            "rules": rules,
            "subjects": subjects,
            "policies": policies,
        },
    }
    rates = {keys.slot_pattern(r, DSP_MODULE, commands_slot(s)): hz for s, hz in SET_POINT_RATES_HZ.items()
             if s in senders} if write_rates is None else dict(write_rates)
    if rates:  # per link, so per identity: a flood is cut where it enters, before it queues on the DSP's link
        config["downsampling"] = [{"id": "write-rates", "messages": ["put"], "flows": ["ingress"],
                                   "rules": [{"key_expr": k, "freq": hz} for k, hz in rates.items()]}]
    if peers or hub_cns:  # it dials other routers ([bus] peers): it presents its own certificate there too
        config["transport"]["link"]["tls"].update({"connect_certificate": cert, "connect_private_key": key})
    return config


ROUTER_LINK = "router-link"
"""The subject id of the robot router's link in a peer module's ingress policy (:func:`peer_ingress_policy`)."""
_THROUGH_ROUTER = ("gcs", "manager", "everyone")
"""Policies of the identities whose traffic reaches a peer module only through the robot's router."""


def peer_ingress_policy(router_access_control: dict[str, Any], router_cn: str, *,
                        ral_is_peer: bool = True) -> dict[str, Any]:
    """The router's ``access_control`` made a peer module's ingress policy (``[bus] links = "peers"``).

    The router's link (certificate CN ``router_cn``) is let in with the rights of what it forwards and nothing
    more: the manager, the ground stations, the named mesh robots (and the RAL when it is not a peer module
    itself). Module identities link to each other directly, so their rights are never the router link's: whoever
    reads ``router.key`` on the robot and dials a module directly gets no module's writes, no DSP command key.
    A hub forwards robots it does not name, so with ``hubs`` the link also gets every robot's writes, with a deny
    on this robot's DSP command keys and RAL keys (docs/security.md, issue 32 item 4)."""
    ac = copy.deepcopy(router_access_control)
    granted: list[str] = []
    hub = False
    for policy in ac["policies"]:
        pid = policy["id"]
        if pid in _THROUGH_ROUTER or pid.startswith("peer-") or (pid == "ral" and not ral_is_peer):
            granted += policy["rules"]
        elif pid == "hub":
            hub = True
            granted += [r for r in policy["rules"] if not r.startswith("hub-not-this-robot")]
    if hub:
        rules = {r["id"]: r for r in ac["rules"]}
        guarded = [k for rid, r in rules.items() if rid.startswith("m-") and rid.endswith("-write")
                   for k in r["key_exprs"] if f"/{DSP_MODULE}/" in k]
        if ral_is_peer:
            guarded += [k for rid in ("ral-write", "ral-requests") if rid in rules for k in rules[rid]["key_exprs"]]
        ac["rules"].append(_rule("router-link-not-modules", [*WRITE, "declare_queryable"], guarded, "deny"))
        granted.append("router-link-not-modules")
    ac["subjects"].append({"id": ROUTER_LINK, "cert_common_names": [router_cn]})
    ac["policies"].append({"id": ROUTER_LINK, "subjects": [ROUTER_LINK], "rules": list(dict.fromkeys(granted))})
    return ac


def hub_config(*, listen: list[str], ca: str, cert: str, key: str, gcs: list[str],
               robots: list[str], revoked: list[str] | None = None) -> dict[str, Any]:
    """A hub (ground) router's config: mTLS on ``tls/`` links and its own policy. Ground stations connected to it
    get a ground station's rights on every robot; each robot's router (``router-<robot>``) may write only its own
    robot's keys; everyone observes. The robots' routers (``[bus] peers``) or the hub (``--connect``) may dial."""
    for name in [*gcs, *robots]:
        keys.validate_name(name, "identity")
    if not gcs:
        raise ValueError("at least one GCS identity is needed")
    rules: list[dict[str, Any]] = [
        _rule("observe", OBSERVE[:3], _read_keys() + _adv_keys()),
        _rule("history", ["query"], _adv_keys()),
        _rule("history-sub", ["liveliness_token"], _adv_sub(_adv_keys())),
        _rule("read-queries", ["query"], READ_QUERIES),
        # a parameter change travels to a module and its answer back only as the manager asked (ingress rules)
        _rule("deliver", ALL_MESSAGES, _read_keys() + _adv_keys() + [module_params_pattern()], flow="egress"),
        _rule("gcs-command", ["query"], _gcs_commands("*")),
        _rule("gcs-link", ["put", "delete", "liveliness_token"], [keys.gcs_pattern(), keys.fleet_task_key("*")]),
    ]
    subjects: list[dict[str, Any]] = [{"id": "gcs", "cert_common_names": list(gcs)}]
    policies: list[dict[str, Any]] = [{"id": "gcs", "subjects": ["gcs"], "rules": ["gcs-command", "gcs-link"]}]
    for name in dict.fromkeys(robots):
        rules += _robot_write_rules(f"robot-{name}", name)
        subjects.append({"id": f"robot-{name}", "cert_common_names": [mesh_router_cn(name)]})
        policies.append({"id": f"robot-{name}", "subjects": [f"robot-{name}"],
                         "rules": [f"robot-{name}-write", f"robot-{name}-token"]})
    policies.append({"id": "everyone", "subjects": [s["id"] for s in subjects],
                     "rules": ["observe", "history", "history-sub", "read-queries", "deliver"]})
    _deny_revoked(rules, subjects, policies, revoked)
    return {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"shared_memory": {"enabled": False}, "link": {"protocols": ["tls"], "tls": {
            "root_ca_certificate": ca, "listen_certificate": cert, "listen_private_key": key,
            "connect_certificate": cert, "connect_private_key": key, "enable_mtls": True,
            "verify_name_on_connect": True}}},
        "access_control": {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
                           "policies": policies},
    }


def _deny_revoked(rules: list[dict[str, Any]], subjects: list[dict[str, Any]], policies: list[dict[str, Any]],
                  revoked: list[str] | None) -> None:
    """Revoked certificate names (``cromat certs --revoke``: Zenoh's TLS checks no CRL) get nothing: a deny of
    every message, both ways, on every key any rule names. A deny wins over the allows the same name still has
    as a listed ground station, so the name stays denied until the router's config is regenerated without it."""
    names = list(dict.fromkeys(revoked or []))
    if not names:
        return
    for name in names:
        keys.validate_name(name, "revoked identity")
    every_key = list(dict.fromkeys(k for r in rules for k in r["key_exprs"]))
    rules.append(_rule("revoked", ALL_MESSAGES, every_key, permission="deny") | {"flows": ["ingress", "egress"]})
    subjects.append({"id": "revoked", "cert_common_names": names})
    policies.append({"id": "revoked", "subjects": ["revoked"], "rules": ["revoked"]})


def write(config: dict[str, Any], path: Path) -> None:
    """Write as JSON5 (plain JSON is valid JSON5) with a header saying where it came from."""
    path.write_text(
        "// robot router config written by `cromat certs --acl` (bbcs/acl.py): mTLS + access policy\n"
        + json.dumps(config, indent=2)
        + "\n"
    )
