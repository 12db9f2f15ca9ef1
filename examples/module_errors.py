"""A bus module refuses an out-of-range datum and says so on its ERROR slot; a good datum has its effect.

Starts :mod:`examples.thermostat` as a process, waits until it is alive (its liveliness token) and reachable,
then writes a cold reading (the heater goes on) and an impossible one (ERROR slot: 1, OUT_OF_RANGE).

    python -m examples.module_errors --connect tcp/127.0.0.1:7447
"""

from __future__ import annotations

import queue
import subprocess
import sys
import threading

import msgspec
import zenoh

from bbcs import BusErrorCode, SessionConfig, keys, open_session
from bbcs.contracts.errors import ErrorReport
from examples.thermostat import Heater, Reading

ROBOT = "demo"


def main(conf: SessionConfig) -> int:
    module = subprocess.Popen([sys.executable, "-m", "examples.thermostat", "--robot", ROBOT,
                               "--connect", conf.connect[0]])
    session = open_session(conf)
    events: queue.Queue[Heater | ErrorReport] = queue.Queue()
    alive = threading.Event()
    try:
        token = session.liveliness().declare_subscriber(keys.alive_key(ROBOT, "thermostat"),
                                                        lambda s: s.kind == zenoh.SampleKind.PUT and alive.set(),
                                                        history=True)
        subs = [session.declare_subscriber(keys.slot_key(ROBOT, "thermostat", slot),
                                           lambda s, d=msgspec.msgpack.Decoder(t).decode: events.put(
                                               d(s.payload.to_bytes())))
                for slot, t in (("heater", Heater), ("error", ErrorReport))]
        pub = session.declare_publisher(keys.slot_key(ROBOT, "thermostat", "reading"))
        if not alive.wait(30):
            print("module_errors: the thermostat never came up")
            return 1
        matched = threading.Event()
        listener = pub.declare_matching_listener(lambda status: status.matching and matched.set())
        if not (pub.matching_status.matching or matched.wait(10)):
            print("module_errors: the thermostat's input is not reachable")
            return 1
        pub.put(msgspec.msgpack.encode(Reading(seq=1, celsius=12.0)))
        pub.put(msgspec.msgpack.encode(Reading(seq=2, celsius=140.0)))
        seen: list[Heater | ErrorReport] = [events.get(timeout=10), events.get(timeout=10)]
        for event in seen:
            print(f"module_errors: {event}")
        heater = [e for e in seen if isinstance(e, Heater)]
        errors = [e for e in seen if isinstance(e, ErrorReport)]
        ok = heater == [Heater(seq=1, on=True)] and errors == [ErrorReport(code=BusErrorCode.OUT_OF_RANGE)]
        for entity in (listener, pub, *subs, token):
            entity.undeclare()
        return 0 if ok else 1
    finally:
        session.close()
        module.terminate()
        module.wait(10)


if __name__ == "__main__":
    from examples._cli import run

    raise SystemExit(run(main, __doc__))
