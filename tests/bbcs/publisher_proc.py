"""A publisher process for the bus tests: waits for a module's liveliness token, publishes numbered ProbeMsgs."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from probe_module import ProbeMsg  # noqa: E402

from bbcs import keys  # noqa: E402
from bbcs.session import local_client, open_session  # noqa: E402
from bbcs.slots import Kind, OutputSlot, Publisher, Safety  # noqa: E402


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--key", required=True)
    p.add_argument("--kind", choices=["state", "stream", "unsafe"], required=True)
    p.add_argument("--count", type=int, required=True)
    p.add_argument("--source", default="x")
    p.add_argument("--rate", type=float, default=0.0, help="messages/s, 0 = as fast as possible")
    p.add_argument("--final", action="store_true", help="after the burst, pause and publish one more (seq=count)")
    p.add_argument("--wait-alive", default="cromat/r1/@alive/probe")
    args = p.parse_args()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    session = open_session(local_client(args.port))
    try:
        kind = Kind.STREAM if args.kind == "stream" else Kind.STATE
        safety = Safety.UNSAFE if args.kind == "unsafe" else Safety.SAFE
        pub = Publisher(session, args.key, OutputSlot("x", ProbeMsg, kind=kind, safety=safety))
        alive = threading.Event()
        tok = session.liveliness().declare_subscriber(args.wait_alive, lambda s: alive.set(), history=True)
        alive.wait(30)
        keys.parse_slot_key(args.key)
        period = 1.0 / args.rate if args.rate else 0.0
        start = time.monotonic()
        for seq in range(args.count):
            if stop.is_set():
                break
            pub.publish(ProbeMsg(source=args.source, seq=seq))
            if period:
                delay = start + (seq + 1) * period - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
        if args.final:
            time.sleep(0.3)
            pub.publish(ProbeMsg(source=args.source, seq=args.count))
        print(f"done {pub.published}", flush=True)
        stop.wait(60)
        tok.undeclare()
        pub.close()
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
