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


try:
    import msgspec as _msgspec

    class DoraMsg(_msgspec.Struct, frozen=True, kw_only=True):
        """bench/bus.py's BenchMsg, field for field (the dora nodes do not import the project)."""

        seq: int
        stamp_ns: int
        value: float = 12.5
        tilt: float = -45.0
        body: bytes = b""
except ImportError:  # only the dora nodes need it
    pass


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


# ------------------------------------------------------------------ dora-rs, confined to a loopback-only netns

DORA_DOC = """dora-rs: its Python nodes run under a dora daemon (``dora run``), whose coordinator, daemon and inter-node
Zenoh session bind ports of their own choosing, with scouting. So the whole dataflow runs inside a fresh Linux network
namespace (``unshare -n``, or ``unshare -rn`` as a user) that has nothing but a loopback interface, brought up inside:
no packet can leave 127.0.0.1 of that namespace, and no port can clash with the machine's. Same message (msgpack,
~40 B), sent as one Arrow binary value; ping-pong with the reply sent from the echo node's event loop; throughput with
the reader's input queue sized so that the daemon's drop-oldest policy does not drop."""

NETNS_SHELL = "ip link set lo up && exec \"$@\""


def on_cpu(cpu: int | None) -> Any:
    """A ``preexec_fn`` that puts the started process, and so everything it starts, on processor ``cpu`` alone:
    what a manifest's ``cpus = [cpu]`` does to two modules (module_manager/process.py). None: no placement."""
    if cpu is None:
        return None
    return lambda: os.sched_setaffinity(0, {cpu})


def unshare_argv() -> list[str]:
    return ["unshare", "-n"] if os.geteuid() == 0 else ["unshare", "-rn"]


def netns_usable() -> str | None:
    """None when a fresh network namespace with nothing but a loopback interface can be made here; else why."""
    import shutil
    import subprocess

    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return "unshare(1) or ip(8) missing: cannot make a loopback-only network namespace"
    probe = subprocess.run([*unshare_argv(), "sh", "-c", NETNS_SHELL + " && ip -o link", "netns"],
                           capture_output=True, text=True, timeout=20)
    if probe.returncode != 0:
        return ("cannot make a loopback-only network namespace here (unshare -n needs root or user namespaces): "
                + (probe.stderr.strip() or f"exit {probe.returncode}"))
    links = [line.split(":")[1].strip() for line in probe.stdout.splitlines() if ":" in line]
    if links != ["lo"]:
        return f"the new network namespace is not loopback-only (links: {links})"
    return None


def dora_available() -> str | None:
    """None when a loopback-only namespace can be made and the ``dora`` CLI and Python node API are there; else why."""

    try:
        import dora  # noqa: F401
        import pyarrow  # noqa: F401
    except Exception as exc:
        return f"dora-rs Python node API not usable: {type(exc).__name__}: {exc} (pip install '.[bench]')"
    cli = dora_cli()
    if cli is None:
        return "the `dora` CLI (pip package dora-rs-cli) is not installed (pip install '.[bench]')"
    why = netns_usable()
    return None if why is None else f"dora's daemon cannot be confined to loopback: {why}"


def dora_cli() -> str | None:
    import shutil

    here = os.path.join(os.path.dirname(sys.executable), "dora")
    return here if os.path.exists(here) else shutil.which("dora")


def dora_run(role_pair: tuple[str, str], count: int, body_len: int, timeout_s: float = 240.0,
             cpu: int | None = None) -> Any:
    """Run a two-node dataflow (``ping``/``echo`` or ``blast``/``sink``) in a loopback-only netns; its JSON result.
    ``cpu``: the whole dataflow (``dora run``, its daemon and both nodes) on that one processor."""
    import subprocess
    import tempfile

    script = os.path.abspath(__file__)
    first, second = role_pair
    with tempfile.TemporaryDirectory(prefix="cromat-dora-") as tmp:
        out = os.path.join(tmp, "result.json")
        common = {"CROMAT_DORA_OUT": out, "CROMAT_DORA_COUNT": str(count), "CROMAT_DORA_BODY": str(body_len)}

        def node(nid: str, inputs: dict[str, Any], outputs: list[str]) -> dict[str, Any]:
            return {"id": nid, "path": sys.executable, "args": f"{script} dora-node {nid}", "inputs": inputs,
                    "outputs": outputs, "env": dict(common)}

        if first == "ping":
            nodes = [node("ping", {"pong": "echo/pong", "tick": "dora/timer/millis/200"}, ["ping"]),
                     node("echo", {"ping": {"source": "ping/ping", "queue_size": 1000}}, ["pong"])]
        else:
            nodes = [node("blast", {"tick": "dora/timer/millis/200"}, ["data"]),
                     node("sink", {"data": {"source": "blast/data", "queue_size": count + 2000},
                                   "tick": "dora/timer/millis/200"}, [])]
        flow = os.path.join(tmp, "dataflow.yml")
        with open(flow, "w") as f:
            json.dump({"nodes": nodes}, f)  # JSON is YAML
        proc = subprocess.run([*unshare_argv(), "sh", "-c", NETNS_SHELL, "netns", dora_cli() or "dora", "run", flow],
                              cwd=tmp, capture_output=True, text=True, timeout=timeout_s, preexec_fn=on_cpu(cpu))
        if not os.path.exists(out):
            raise RuntimeError(f"dora run left no result (exit {proc.returncode}): {proc.stderr[-800:]}")
        with open(out) as f:
            return json.load(f)


def dora_node(nid: str) -> None:
    """One node of the dora dataflow (started by the dora daemon, inside the namespace)."""
    import msgspec
    import pyarrow as pa
    from dora import Node

    count, body = int(os.environ["CROMAT_DORA_COUNT"]), b"x" * int(os.environ["CROMAT_DORA_BODY"])
    out = os.environ["CROMAT_DORA_OUT"]
    enc, dec = msgspec.msgpack.Encoder(), msgspec.msgpack.Decoder(DoraMsg)

    def value(seq: int) -> Any:
        return pa.array([enc.encode(DoraMsg(seq=seq, stamp_ns=time.perf_counter_ns(), body=body))], type=pa.binary())

    node = Node()
    if nid == "echo":
        for event in node:
            if event["type"] != "INPUT":
                if event["type"] == "STOP":
                    break
                continue
            node.send_output("pong", event["value"])
            if dec.decode(event["value"][0].as_py()).seq < 0:
                break
    elif nid == "ping":
        samples: list[float] = []
        expected = 0
        for event in node:
            if event["type"] != "INPUT":
                if event["type"] == "STOP":
                    break
                continue
            if event["id"] == "tick":
                if expected == 0:  # the echo may not be subscribed yet: ping again until the first pong
                    node.send_output("ping", value(0))
                continue
            msg = dec.decode(event["value"][0].as_py())
            if msg.seq != expected:
                continue
            samples.append((time.perf_counter_ns() - msg.stamp_ns) / 2000.0)
            expected += 1
            if len(samples) >= count:
                break
            node.send_output("ping", value(expected))
        node.send_output("ping", value(-1))
        _write(out, samples)
    elif nid == "blast":
        for event in node:
            if event["type"] == "INPUT" and event["id"] == "tick":
                break
        time.sleep(0.5)
        data = value(0)
        for _ in range(count):  # exactly count: the sink's count (it stops 3 s after the last) is the delivered share
            node.send_output("data", data)
    elif nid == "sink":
        n, first, last = 0, 0.0, 0.0
        for event in node:
            if event["type"] == "STOP":
                break
            if event["type"] != "INPUT":
                continue
            now = time.perf_counter()
            if event["id"] == "tick":
                if n and now - last > 3.0:
                    break
                continue
            n += 1
            if n == 1:
                first = now
            last = now
            if n >= count:
                break
        _write(out, {"n": n, "seconds": last - first, "sent": count})


def _write(path: str, obj: Any) -> None:
    tmp = path + ".part"
    with open(tmp, "w") as f:
        json.dump(obj, f)
    os.replace(tmp, path)


if __name__ == "__main__" and len(sys.argv) >= 3 and sys.argv[1] == "dora-node":
    dora_node(sys.argv[2])
