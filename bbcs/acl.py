"""The robot router's access policy, generated from the identities it must know.

Zenoh enforces access control on the links that arrive at the router that configures it, so this policy
goes on the robot's router (``cromat router --config FILE``). Identities are certificate common names under
mutual TLS. Default deny; then:

* every authenticated identity may observe: subscribe, liveliness, schema and read-only MRI queries, and
  receive everything (so reading state works for all);
* the bookkeeping of zenoh.ext advanced pub/sub (``…/@adv/**``: caches, heartbeats, liveliness) is open to
  all, because ``**`` never matches the verbatim ``@adv`` chunk;
* only a GCS identity may submit tasks (``@ral/task``) and swap routes (``@manager/route``);
* the RAL writes its own keys and asks the manager anything; the manager writes control slots and its keys;
* a module writes only its own slots (plus the mailbox slots named, e.g. ``dsp/commands``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bbcs import keys

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


def _keys() -> dict[str, list[str]]:
    """Keys anyone authenticated may observe, for every robot (a GCS lists robots with ``cromat/*/...``)."""
    return {
        "read": [
            keys.slot_pattern(),
            keys.schema_pattern(),
            keys.route_ack_pattern(),
            keys.heartbeat_pattern(),
            keys.alive_pattern(),
            keys.manager_pattern(),
            keys.ral_pattern(),
            keys.gcs_pattern(),
        ],
        "adv": [
            keys.adv_pattern(keys.slot_pattern()),
            keys.adv_pattern(keys.route_ack_pattern()),
            keys.adv_pattern(keys.manager_key("*") + "/*"),
            keys.adv_pattern(keys.ral_key("*") + "/*"),
        ],
        "read_queries": [
            keys.schema_pattern(),
            keys.manager_key("*", "modules"),
            keys.manager_key("*", "routes"),
            keys.manager_key("*", "tasks"),
        ],
    }


def _own(robot: str, name: str) -> list[str]:
    return [keys.slot_pattern(robot, name), keys.route_ack_pattern(robot, name), keys.heartbeat_pattern(robot, name)]


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
    mailboxes: tuple[str, ...] = ("dsp/commands",),
    identities: dict[str, str] | None = None,
) -> dict[str, Any]:
    """A complete Zenoh router config: ``tls/`` listeners with mTLS and the access policy above.

    ``identities`` maps a module name (or ``ral``) to the certificate CN it presents when that differs from the
    name; the module's rights stay keyed by its name (its slots are ``cromat/<robot>/<name>/*``).
    """
    cn = dict(identities or {})
    if robot != "*":
        keys.validate_name(robot, "robot name")
    for name in [*gcs, *modules, ral, manager, *(identities or {}).values()]:
        keys.validate_name(name, "identity")
    if not gcs:
        raise ValueError("at least one GCS identity is needed")
    k = _keys()
    rules: list[dict[str, Any]] = [
        {
            "id": "observe",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"],
            "key_exprs": k["read"] + k["adv"],
        },
        {
            "id": "deliver",
            "permission": "allow",
            "flows": ["egress"],
            "messages": ALL_MESSAGES,
            "key_exprs": k["read"] + k["adv"],
        },
        {
            "id": "adv",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ALL_MESSAGES,
            "key_exprs": k["adv"],
        },
        {
            "id": "replies",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["reply"],
            "key_exprs": k["read"],
        },
        {
            "id": "read-queries",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["query"],
            "key_exprs": k["read_queries"],
        },
        {
            "id": "gcs-command",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["query"],
            "key_exprs": [keys.ral_key(robot, "task"), keys.manager_key(robot, "route")],
        },
        {
            "id": "gcs-link",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["put", "delete", "liveliness_token"],
            "key_exprs": [keys.gcs_pattern()],
        },
        {
            "id": "ral-write",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["put", "delete"],
            "key_exprs": [*_own(robot, ral), keys.ral_pattern(robot)],
        },
        {
            "id": "ral-serve",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["declare_queryable"],
            "key_exprs": [keys.ral_pattern(robot), keys.schema_pattern(robot, ral)],
        },
        {
            "id": "ral-token",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["liveliness_token"],
            "key_exprs": [keys.alive_pattern(robot, ral)],
        },
        {
            "id": "ral-mri",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["query"],
            "key_exprs": [keys.manager_pattern(robot)],
        },
        {
            "id": "manager-write",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["put", "delete"],
            "key_exprs": [keys.slot_pattern(robot), keys.manager_pattern(robot), *_own(robot, manager)],
        },
        {
            "id": "manager-serve",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["declare_queryable", "liveliness_token"],
            "key_exprs": [
                keys.manager_pattern(robot),
                keys.schema_pattern(robot, manager),
                keys.alive_pattern(robot),
            ],
        },
    ]
    subjects: list[dict[str, Any]] = [
        {"id": "gcs", "cert_common_names": list(gcs)},
        {"id": "ral", "cert_common_names": [cn.get("ral", ral)]},
        {"id": "manager", "cert_common_names": [manager]},
    ]
    policies: list[dict[str, Any]] = [
        {"id": "gcs", "subjects": ["gcs"], "rules": ["gcs-command", "gcs-link"]},
        {"id": "ral", "subjects": ["ral"], "rules": ["ral-write", "ral-serve", "ral-token", "ral-mri"]},
        {"id": "manager", "subjects": ["manager"], "rules": ["manager-write", "manager-serve"]},
    ]
    for name in modules:
        own = _own(robot, name)
        rules += [
            {
                "id": f"m-{name}-write",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": ["put", "delete"],
                "key_exprs": own + [keys.slot_pattern(robot, *box.split("/", 1)) for box in mailboxes],
            },
            {
                "id": f"m-{name}-serve",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": ["declare_queryable"],
                "key_exprs": [keys.schema_pattern(robot, name)],
            },
            {
                "id": f"m-{name}-token",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": ["liveliness_token"],
                "key_exprs": [keys.alive_pattern(robot, name)],
            },
        ]
        subjects.append({"id": f"m-{name}", "cert_common_names": [cn.get(name, name)]})
        policies.append(
            {
                "id": f"m-{name}",
                "subjects": [f"m-{name}"],
                "rules": [f"m-{name}-write", f"m-{name}-serve", f"m-{name}-token"],
            }
        )
    everyone = [s["id"] for s in subjects]
    policies.append(
        {
            "id": "everyone",
            "subjects": everyone,
            "rules": ["observe", "deliver", "adv", "replies", "read-queries"],
        }
    )
    return {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {
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


def write(config: dict[str, Any], path: Path) -> None:
    """Write as JSON5 (plain JSON is valid JSON5) with a header saying where it came from."""
    path.write_text(
        "// robot router config written by `cromat certs --acl` (bbcs/acl.py): mTLS + access policy\n"
        + json.dumps(config, indent=2)
        + "\n"
    )
