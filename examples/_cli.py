"""The one command-line option every example takes: which router to connect to."""

from __future__ import annotations

import argparse
from collections.abc import Callable

from bbcs import SessionConfig


def run(main: Callable[[SessionConfig], int], description: str, argv: list[str] | None = None) -> int:
    """Parse ``--connect ENDPOINT`` (default: a robot router on this machine) and call ``main``."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--connect", default="tcp/127.0.0.1:7447", metavar="ENDPOINT", help="the router to join")
    args = p.parse_args(argv)
    return main(SessionConfig(mode="client", connect=[args.connect]))
