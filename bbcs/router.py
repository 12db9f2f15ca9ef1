"""``cromat router``: the robot's Zenoh router, a small process of its own, started first.

It is zenoh-python in router mode, so a laptop needs nothing but this package. Access control and TLS come
from a Zenoh JSON5 file (``--config``) or the TLS options. A config with write-rate limits (Zenoh's
``downsampling``, as the generated robot policy has) also names the floods those limits cut, in this log, once a
second per sender and key (bbcs/router_floods.py).

*Live revocation* (``--revoked FILE``, the robot folder's ``revoked.txt`` that ``cromat certs --revoke`` writes):
Zenoh's TLS checks no CRL and its access policy is read once, when the session opens. The router looks at the
file every ``REVOKED_POLL_S``; when a name is added it writes its config again with a deny of every message for
the revoked names (as the generated policy has at launch, bbcs/acl.py) beside the original
(``<config stem>.live.json5``) and reopens its session on it: every link drops and reconnects through the new
policy (modules and ground stations reconnect by themselves, as after a router restart), and the revoked identity
gets nothing from then on. A name taken off the file stays denied until the next launch (a revoked name is never
issued again).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import threading
from pathlib import Path
from typing import Any

import msgspec

from bbcs import acl, keys, router_audit, router_floods
from bbcs.errors import SessionError
from bbcs.session import SessionConfig, TlsConfig, open_session
from bbcs.stop_signals import exit_deadline, forward_stop_signals


def robot_router_zid(robot: str) -> str:
    """The Zenoh id of robot ``robot``'s router: the same for every router of that name, different for any other.

    Zenoh refuses a link from a router whose id is already linked (its own, or one it holds a link with), so two
    robots of one name can never be on one mesh at once: the second router's links to the mesh are closed at
    the handshake ("reason INVALID"), whenever it joins (at start, later, or at the same instant as the first),
    and nothing of it crosses. ``cromat launch`` starts every robot's router with ``--robot``."""
    return hashlib.sha256(f"cromat robot router {robot}".encode()).hexdigest()[:32]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cromat router", description="Run a robot's Zenoh router.")
    p.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable), default tcp/127.0.0.1:7447")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="another router to connect to (repeatable)")
    p.add_argument("--config", metavar="FILE", help="Zenoh JSON5 config file (access control, auth, tuning)")
    p.add_argument("--tls-ca", metavar="PEM", help="CA certificate for tls/ endpoints")
    p.add_argument("--tls-cert", metavar="PEM", help="router certificate for tls/ endpoints")
    p.add_argument("--tls-key", metavar="PEM", help="router private key for tls/ endpoints")
    p.add_argument("--robot", metavar="NAME",
                   help="the robot this router serves: its Zenoh id comes from the name, so the mesh refuses a "
                        "second robot of the same name (and this router says so when refused)")
    p.add_argument("--scouting", action="store_true", help="enable UDP multicast scouting (off by default)")
    p.add_argument("--admin-space", action="store_true",
                   help="answer queries on Zenoh's admin space @/<zid>/router/** (read-only; off by default)")
    p.add_argument("--log-refusals", action="store_true",
                   help="log denied messages and refused TLS links, counted and rate limited (bbcs/router_audit.py)")
    p.add_argument("--revoked", metavar="FILE",
                   help="revoked certificate names, one a line (revoked.txt): watched, and a name added there is "
                        "denied everything at once (the session reopened on the regenerated policy; needs --config)")
    return p


REVOKED_POLL_S = 1.0
"""How often ``--revoked`` is looked at."""
EXIT_DEADLINE_S = 10
"""Seconds a stopping router has to close its session and exit before SIGALRM (default action) ends it."""


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    tls = None
    if args.tls_ca:
        tls = TlsConfig(root_ca=args.tls_ca, cert=args.tls_cert, key=args.tls_key)
    cfg = SessionConfig(mode="router", listen=args.listen or ["tcp/127.0.0.1:7447"], connect=args.connect,
                        multicast_scouting=args.scouting, tls=tls, config_file=args.config,
                        admin_space=args.admin_space, zid=robot_router_zid(args.robot) if args.robot else None)
    floods = router_floods.FloodLog() if _limits_writes(args.config) else None
    if args.log_refusals or args.robot or floods is not None:  # before the session: Zenoh's log through the reader
        sys.stdout = os.fdopen(os.dup(1), "w", buffering=1)
        log_filter = router_audit.LOG_FILTER if args.log_refusals else router_audit.LINK_LOG_FILTER
        router_audit.install(sys.stdout, log_filter=log_filter + (f",{router_floods.LOG_TARGET}" if floods else ""),
                             consume=floods.feed if floods is not None else None)
        if floods is not None:  # room for a flood's burst of lines while the reader catches up (1 MiB, Linux)
            try:
                import fcntl

                fcntl.fcntl(1, getattr(fcntl, "F_SETPIPE_SZ", 1031), 1 << 20)
            except OSError:  # over /proc/sys/fs/pipe-max-size for this user: the default 64 KiB
                pass
    stop = threading.Event()
    restore_signals = forward_stop_signals(lambda _signum: stop.set())  # never a lock in a handler
    try:
        session = open_session(cfg)
    except SessionError as exc:
        restore_signals()
        print(f"cromat router: {exc}", file=sys.stderr)
        return 2
    current = [session]
    try:
        print(f"cromat router: listening on {', '.join(cfg.listen)} (zid {session.zid()})", flush=True)
        if floods is not None:
            floods.names = lambda: router_floods.link_names(current[0])()
            router_floods.start_reporting(floods, sys.stdout, stop)
        if args.revoked and args.config:
            seen = denied_in_config(Path(args.config))  # a name the file has and the policy not: reloaded at once
            while not stop.wait(REVOKED_POLL_S):
                names = read_revoked(Path(args.revoked))
                added = sorted(set(names) - seen)
                if not added:
                    continue
                try:
                    live = revoke_in_config(Path(args.config), sorted(seen | set(names)))
                except (OSError, ValueError) as exc:
                    print(f"cromat router: {args.revoked} names {', '.join(added)} but the policy cannot be "
                          f"regenerated ({exc}): the running policy is kept", flush=True)
                    seen |= set(added)
                    continue
                seen |= set(names)
                current[0].close()
                try:
                    current[0] = open_session(msgspec.structs.replace(cfg, config_file=str(live)))
                except SessionError as exc:  # never left without a router: back on the policy it had
                    current[0] = open_session(cfg)
                    print(f"cromat router: revoked {', '.join(added)} but the regenerated policy did not open "
                          f"({exc}): the previous policy is back", flush=True)
                    continue
                cfg = msgspec.structs.replace(cfg, config_file=str(live))
                print(f"cromat router: revoked {', '.join(added)}: policy reloaded ({live.name}), every link "
                      "reconnected through it", flush=True)
        else:
            stop.wait()
    finally:
        # stopping: a second signal ends the process, and so does the kernel if closing and exiting take longer
        # than EXIT_DEADLINE_S (measured under load: a router SIGTERMed with its manager SIGKILLed stayed over 30 s)
        restore_signals()
        exit_deadline(EXIT_DEADLINE_S)
        current[0].close()
    return 0


def read_revoked(path: Path) -> list[str]:
    """The names in a revoked list (one a line; blank lines skipped); none if the file is not there."""
    try:
        return [line.strip() for line in path.read_text().splitlines() if line.strip()]
    except FileNotFoundError:
        return []


def _load_policy(config: Path) -> dict[str, Any]:
    text = "\n".join(line for line in config.read_text().splitlines() if not line.lstrip().startswith("//"))
    try:
        data: dict[str, Any] = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{config} is not the generated JSON policy: {exc}") from None
    return data


def denied_in_config(config: Path) -> set[str]:
    """The revoked names ``config``'s policy already denies (none if it is not the generated JSON policy)."""
    try:
        subjects = _load_policy(config).get("access_control", {}).get("subjects", [])
    except (OSError, ValueError):
        return set()
    return {cn for x in subjects if x.get("id") in ("revoked", "revoked-live") for cn in x.get("cert_common_names", [])}


def revoke_in_config(config: Path, names: list[str]) -> Path:
    """Write ``<config stem>.live.json5``: ``config`` (JSON with ``//`` comment lines, as the launch writes it)
    with every message of ``names`` denied both ways on every key its rules name; its path. ValueError: not such a
    config."""
    for name in names:
        keys.validate_name(name, "revoked identity")
    data = _load_policy(config)
    ac = data.get("access_control")
    if not isinstance(ac, dict) or not ac.get("rules"):
        raise ValueError(f"{config} has no access policy to add the revoked names to")
    every_key = list(dict.fromkeys(k for r in ac["rules"] for k in r["key_exprs"]))
    ac["rules"] = [r for r in ac["rules"] if r["id"] != "revoked-live"] + [{
        "id": "revoked-live", "permission": "deny", "flows": ["ingress", "egress"], "key_exprs": every_key,
        "messages": list(acl.ALL_MESSAGES)}]
    ac["subjects"] = [x for x in ac["subjects"] if x["id"] != "revoked-live"] + [
        {"id": "revoked-live", "cert_common_names": names}]
    ac["policies"] = [x for x in ac["policies"] if x["id"] != "revoked-live"] + [
        {"id": "revoked-live", "subjects": ["revoked-live"], "rules": ["revoked-live"]}]
    live = config.with_name(config.stem + ".live.json5")
    live.write_text("// written by cromat router from " + config.name + " and its revoked list\n"
                    + json.dumps(data, indent=2) + "\n")
    live.chmod(0o600)
    return live


def _limits_writes(config: str | None) -> bool:
    """True if the Zenoh config file has write-rate limits (a ``downsampling`` section)."""
    if not config:
        return False
    try:
        with open(config, encoding="utf-8") as f:
            text = f.read()
        return '"downsampling"' in text or "downsampling:" in text
    except OSError:  # the session's own open reports the unreadable file
        return False


if __name__ == "__main__":
    raise SystemExit(main())
