"""The connection options every tool shares (``--connect`` and the TLS options, as ``cromat gcs`` has them)."""

from __future__ import annotations

import argparse

import zenoh

from bbcs.errors import SessionError
from bbcs.session import SessionConfig, open_session
from ral.gcs.api import UsageError, session_config


class ToolError(RuntimeError):
    """A tool cannot do what was asked; the message says why (exit code 2 unless stated)."""

    def __init__(self, message: str, code: int = 2) -> None:
        super().__init__(message)
        self.code = code


def add_connection_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="robot router endpoint, e.g. tls/robot1:7447 (repeatable; default tcp/127.0.0.1:7447)")
    p.add_argument("--ca", help="CA certificate (PEM) that signed the router's certificate (tls/)")
    p.add_argument("--cert", help="this station's certificate (PEM) for mutual TLS")
    p.add_argument("--key", help="this station's private key (PEM)")
    p.add_argument("--config", metavar="FILE", help="Zenoh JSON5 config file (applied first)")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the router and answers")


def config_from(args: argparse.Namespace) -> SessionConfig:
    try:
        return session_config(args.connect, ca=args.ca, cert=args.cert, key=args.key, config_file=args.config,
                              connect_timeout_s=args.timeout)
    except UsageError as exc:
        raise ToolError(str(exc)) from None


def connect(args: argparse.Namespace) -> zenoh.Session:
    """Open a client session of the router the options name (ToolError with exit code 3 if unreachable)."""
    cfg = config_from(args)
    try:
        return open_session(cfg)
    except SessionError as exc:
        raise ToolError(f"cannot reach the robot router: {exc}", 3) from None
