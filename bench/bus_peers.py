"""The bus's peers, measured the way ``bench/bus.py`` measures a slot: Eclipse Cyclone DDS's Python binding.

Same ~40 B message (seq, stamp, two floats, a body), same ping-pong (one-way = RTT/2, the reply sent from the
receiving side as soon as it has the sample) and the same throughput method (a writer blasting, a reader counting),
reliable delivery with keep-all history so nothing is lost. Cyclone is confined to loopback: unicast only,
multicast off, the one peer 127.0.0.1; its discovery ports follow from the DDS domain id, which is drawn at random
per run (DDS has no "free port" of its own).
"""


import json
import os
import random
import sys
import time
from dataclasses import dataclass
from typing import Any

CYCLONE_XML = """<CycloneDDS><Domain id="any"><General><Interfaces><NetworkInterface name="lo"/></Interfaces>
<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>
<MaxAutoParticipantIndex>30</MaxAutoParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers></Discovery>
</Domain></CycloneDDS>"""


def cyclone_available() -> str | None:
    """None when the binding imports, else why the peer cannot run here."""
    try:
        import cyclonedds.domain  # noqa: F401
    except Exception as exc:  # not installed, or its C library does not load
        return f"cyclonedds not usable: {type(exc).__name__}: {exc} (pip install '.[bench]')"
    return None


def cyclone_env(domain: int) -> dict[str, str]:
    return {"CYCLONEDDS_URI": CYCLONE_XML, "CROMAT_DDS_DOMAIN": str(domain)}


def new_domain() -> int:
    return random.randrange(1, 200)


def _dds() -> tuple[Any, ...]:
    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl.types import float64, int64, sequence, uint8
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    @dataclass
    class BenchMsg(IdlStruct, typename="BenchMsg"):
        seq: int64
        stamp_ns: int64
        value: float64
        tilt: float64
        body: sequence[uint8]

    qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepAll,
              Policy.ResourceLimits(max_samples=100_000))
    dp = DomainParticipant(int(os.environ["CROMAT_DDS_DOMAIN"]))
    return dp, BenchMsg, qos, Topic, DataWriter, DataReader, duration


def cyclone_role(role: str, count: int, body_len: int) -> None:
    """Run one side of the Cyclone DDS measurement (child process); prints JSON on stdout when it has a result."""
    dp, msg_t, qos, topic_t, writer_t, reader_t, duration = _dds()
    body = [120] * body_len
    ping_t, pong_t, data_t = (topic_t(dp, name, msg_t) for name in ("cromat_ping", "cromat_pong", "cromat_data"))
    if role == "echo":
        reader, writer = reader_t(dp, ping_t, qos=qos), writer_t(dp, pong_t, qos=qos)
        print("ready", flush=True)
        for sample in reader.take_iter(timeout=duration(seconds=30)):
            writer.write(sample)
            if sample.seq < 0:
                break
    elif role == "ping":
        reader, writer = reader_t(dp, pong_t, qos=qos), writer_t(dp, ping_t, qos=qos)
        _wait_matched(writer)
        time.sleep(0.2)
        samples: list[float] = []
        writer.write(msg_t(seq=0, stamp_ns=time.perf_counter_ns(), value=12.5, tilt=-45.0, body=body))
        for sample in reader.take_iter(timeout=duration(seconds=10)):
            samples.append((time.perf_counter_ns() - sample.stamp_ns) / 2000.0)
            if len(samples) >= count:
                break
            writer.write(msg_t(seq=sample.seq + 1, stamp_ns=time.perf_counter_ns(), value=12.5, tilt=-45.0,
                               body=body))
        writer.write(msg_t(seq=-1, stamp_ns=0, value=0.0, tilt=0.0, body=[]))
        print(json.dumps(samples), flush=True)
    elif role == "sink":
        reader = reader_t(dp, data_t, qos=qos)
        print("ready", flush=True)
        n, first, last = 0, 0.0, 0.0
        while n < count:
            got = reader.take(N=4096)
            if not got:
                if n and time.perf_counter() - last > 10:
                    break
                time.sleep(0.0005)
                continue
            now = time.perf_counter()
            if n == 0:
                first = now
            n += len(got)
            last = now
        print(json.dumps({"n": n, "seconds": last - first}), flush=True)
    elif role == "blast":
        writer = writer_t(dp, data_t, qos=qos)
        _wait_matched(writer)
        time.sleep(0.2)
        msg = msg_t(seq=0, stamp_ns=0, value=12.5, tilt=-45.0, body=body)
        for _ in range(count + 1000):
            writer.write(msg)
        sys.stdin.read()


def _wait_matched(writer: Any, deadline_s: float = 20.0) -> None:
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if writer.get_matched_subscriptions():
            return
        time.sleep(0.01)
    raise SystemExit("cyclonedds: no reader matched within 20 s")
