"""A two-module bus demo on a private router: a sensor publishes, a consumer validates and reacts.

``cromat demo`` starts a router on a free 127.0.0.1 port, a consumer module in a child process, and publishes
a few good and one out-of-range datum; the consumer handles the good ones and reports the bad one on ERROR.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from typing import Annotated

import msgspec

from bbcs import keys
from bbcs.module import Module
from bbcs.session import local_client, open_session
from bbcs.slots import InputSlot, OutputSlot
from bbcs.testing import Processes, start_router


class Reading(msgspec.Struct, frozen=True, kw_only=True):
    """A temperature reading; the range is the validation."""

    seq: int
    celsius: Annotated[float, msgspec.Meta(ge=-40.0, le=85.0)]


class DemoError(msgspec.Struct, frozen=True, kw_only=True):
    error_demo: int


class Consumer(Module):
    name = "consumer"
    slots = (InputSlot("reading", Reading), OutputSlot("error", DemoError))
    error_slot = "error"

    def on_reading(self, value: Reading) -> None:
        print(f"consumer: reading {value.seq}: {value.celsius:.1f} °C", flush=True)


def main(argv: list[str] | None = None) -> int:
    argparse.ArgumentParser(prog="cromat demo", description=__doc__).parse_args(argv)
    procs = Processes()
    try:
        port = start_router(procs)
        print(f"demo: router on tcp/127.0.0.1:{port}")
        procs.start(["-m", "examples.bus_demo_consumer", "--robot", "demo", "--connect", f"tcp/127.0.0.1:{port}"])
        session = open_session(local_client(port))
        try:
            ready = threading.Event()
            token = session.liveliness().declare_subscriber(keys.alive_key("demo", "consumer"),
                                                            lambda s: ready.set(), history=True)
            if not ready.wait(20):
                print("demo: the consumer never came up", file=sys.stderr)
                return 1
            errors = threading.Event()
            decode = msgspec.msgpack.Decoder(DemoError).decode
            err_sub = session.declare_subscriber(
                keys.slot_key("demo", "consumer", "error"),
                lambda s: (print(f"demo: ERROR slot says {decode(s.payload.to_bytes()).error_demo}"), errors.set()))
            pub = session.declare_publisher(keys.slot_key("demo", "consumer", "reading"))
            for seq, celsius in enumerate([21.5, 22.0, 140.0, 22.5]):
                pub.put(msgspec.msgpack.encode(Reading(seq=seq, celsius=celsius)))
                time.sleep(0.1)
            errors.wait(5)
            time.sleep(0.3)
            for entity in (pub, err_sub, token):
                entity.undeclare()
        finally:
            session.close()
    finally:
        procs.stop_all()
    print("demo: done")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
