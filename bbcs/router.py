"""``cromat router``: the robot's Zenoh router, a small process of its own, started first.

It is zenoh-python in router mode, so a laptop needs nothing but this package. Access control and TLS come
from a Zenoh JSON5 file (``--config``) or the TLS options. A config with write-rate limits (Zenoh's
``downsampling``, as the generated robot policy has) also names the floods those limits cut, in this log, once a
second per sender and key (bbcs/router_floods.py).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import threading

from bbcs import router_audit, router_floods
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
    return p


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
        if floods is not None:  # a flood's lines never stall the router: past a full pipe they are lost, not waited
            os.set_blocking(1, False)  # for (Zenoh writes its log on fd 1 from the thread routing the message)
    stop = threading.Event()
    restore_signals = forward_stop_signals(lambda _signum: stop.set())  # never a lock in a handler
    try:
        session = open_session(cfg)
    except SessionError as exc:
        restore_signals()
        print(f"cromat router: {exc}", file=sys.stderr)
        return 2
    try:
        print(f"cromat router: listening on {', '.join(cfg.listen)} (zid {session.zid()})", flush=True)
        if floods is not None:
            floods.names = router_floods.link_names(session)
            router_floods.start_reporting(floods, sys.stdout, stop)
        stop.wait()
    finally:
        # stopping: a second signal ends the process, and so does the kernel if closing and exiting take longer
        # than EXIT_DEADLINE_S (measured under load: a router SIGTERMed with its manager SIGKILLed stayed over 30 s)
        restore_signals()
        exit_deadline(EXIT_DEADLINE_S)
        session.close()
    return 0


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
