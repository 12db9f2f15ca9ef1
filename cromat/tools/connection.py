"""The connection options every tool shares (``--connect`` and the TLS options, as ``cromat gcs`` has them, with
the same environment defaults ``CROMAT_GCS_CONNECT``, ``CROMAT_GCS_CA``, ``CROMAT_GCS_CERT``, ``CROMAT_GCS_KEY``,
``CROMAT_GCS_CONFIG``).

One endpoint: a Zenoh client of that router. Several: a Zenoh client reaches only the first router it gets to, so
the tool joins as a peer linked to every router named (listening nowhere, no multicast): each router's robots are
then seen together. ``ral.gcs.api.session_config`` decides this once, for ``cromat gcs`` and every tool alike.
"""

from __future__ import annotations

import argparse
import os

import zenoh

from bbcs import SessionConfig, SessionError, open_session
from ral.gcs.api import UsageError, session_config


class ToolError(RuntimeError):
    """A tool cannot do what was asked; the message says why (exit code 2 unless stated)."""

    def __init__(self, message: str, code: int = 2) -> None:
        super().__init__(message)
        self.code = code


def env_endpoints() -> list[str] | None:
    """``CROMAT_GCS_CONNECT``'s comma-separated endpoints (None when unset)."""
    return [e.strip() for e in os.environ.get("CROMAT_GCS_CONNECT", "").split(",") if e.strip()] or None


class _Endpoints(argparse.Action):
    """``--connect`` repeatable; given once or more, it replaces the environment's endpoints (not added to them)."""

    def __call__(self, parser: argparse.ArgumentParser, ns: argparse.Namespace, value: object, *_: object) -> None:
        given = getattr(ns, "_connect_given", False)
        ns.connect = [*(ns.connect if given else []), str(value)]
        ns._connect_given = True


def add_connection_options(p: argparse.ArgumentParser) -> None:
    env = os.environ
    p.add_argument("--connect", action=_Endpoints, metavar="ENDPOINT", default=env_endpoints(),
                   help="robot router endpoint, e.g. tls/robot1:7447 (repeatable: every router named is reached; "
                        "env CROMAT_GCS_CONNECT, comma-separated; default tcp/127.0.0.1:7447)")
    p.add_argument("--ca", default=env.get("CROMAT_GCS_CA"),
                   help="CA certificate (PEM) that signed the router's certificate (tls/; env CROMAT_GCS_CA)")
    p.add_argument("--cert", default=env.get("CROMAT_GCS_CERT"),
                   help="this station's certificate (PEM) for mutual TLS (env CROMAT_GCS_CERT)")
    p.add_argument("--key", default=env.get("CROMAT_GCS_KEY"), help="this station's private key (PEM) (env "
                   "CROMAT_GCS_KEY)")
    p.add_argument("--config", metavar="FILE", default=env.get("CROMAT_GCS_CONFIG"),
                   help="Zenoh JSON5 config file, applied first (env CROMAT_GCS_CONFIG)")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the router and answers")


def config_from(args: argparse.Namespace) -> SessionConfig:
    try:
        cfg = session_config(args.connect, ca=args.ca, cert=args.cert, key=args.key, config_file=args.config,
                             connect_timeout_s=args.timeout)
    except UsageError as exc:
        raise ToolError(str(exc)) from None
    return cfg


def connect(args: argparse.Namespace) -> zenoh.Session:
    """Open a client session of the router the options name (ToolError with exit code 3 if unreachable)."""
    cfg = config_from(args)
    try:
        return open_session(cfg)
    except SessionError as exc:
        raise ToolError(f"cannot reach the robot router: {exc}", 3) from None
