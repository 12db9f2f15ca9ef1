"""A slot carries one msgspec struct, packed as msgpack; its ranges live in the type, so decoding validates.

A writer session publishes two readings on ``cromat/demo/thermometer/reading``; a reader session decodes them
with the slot's struct: 21.5 °C is accepted, 140 °C is refused by the decoder itself (no hand-written check).

    python -m examples.typed_slot --connect tcp/127.0.0.1:7447
"""

from __future__ import annotations

import queue
import threading
from typing import Annotated

import msgspec
import zenoh

from bbcs import SessionConfig, keys, open_session

KEY = keys.slot_key("demo", "thermometer", "reading")


class Reading(msgspec.Struct, frozen=True, kw_only=True):
    seq: int
    celsius: Annotated[float, msgspec.Meta(ge=-40.0, le=85.0)]


def main(conf: SessionConfig) -> int:
    decode = msgspec.msgpack.Decoder(Reading).decode
    received: queue.Queue[Reading | msgspec.ValidationError] = queue.Queue()

    def on_sample(sample: zenoh.Sample) -> None:
        try:
            received.put(decode(sample.payload.to_bytes()))
        except msgspec.ValidationError as exc:
            received.put(exc)

    reader, writer = open_session(conf), open_session(conf)
    try:
        sub = reader.declare_subscriber(KEY, on_sample)
        pub = writer.declare_publisher(KEY)
        matched = threading.Event()  # readiness: the router routes this publisher to a subscriber
        listener = pub.declare_matching_listener(lambda status: status.matching and matched.set())
        if not (pub.matching_status.matching or matched.wait(10)):
            print("typed_slot: no subscriber reachable")
            return 1
        for seq, celsius in enumerate([21.5, 140.0]):
            pub.put(msgspec.msgpack.encode(Reading(seq=seq, celsius=celsius)))  # constructing does not validate
        accepted = refused = 0
        for _ in range(2):
            item = received.get(timeout=10)
            if isinstance(item, Reading):
                accepted += 1
                print(f"typed_slot: accepted reading {item.seq}: {item.celsius} °C")
            else:
                refused += 1
                print(f"typed_slot: refused by the decoder: {item}")
        listener.undeclare()
        pub.undeclare()
        sub.undeclare()
        return 0 if (accepted, refused) == (1, 1) else 1
    finally:
        writer.close()
        reader.close()


if __name__ == "__main__":
    from examples._cli import run

    raise SystemExit(run(main, __doc__))
