"""Bus benchmark: one-way latency and throughput between two processes, raw zenoh-python vs a ``bbcs`` slot.

Both sides run in the same harness in the same run, with the same QoS (reliable, BLOCK), in the robot's two
topologies (``[bus] links``): clients of one router (``raw``/``bbcs``), and Zenoh peers linked directly
(``rawpeer``/``bbcspeer``). Raw is ``put(bytes)`` → Python callback; bbcs is ``Publisher.publish(struct)`` → the
Module's event loop → decode + validate → handler. Latency is ping-pong (RTT/2), each reply sent from the
receiving handler. Throughput is a publisher blasting as fast as it can into a handler that counts.

    python bench/bus.py            # defaults: ~1-2 minutes; table on stdout, JSON in bench/results/bus.json
    python bench/bus.py --peers    # + Cyclone DDS, dora-rs, UDP floor (loopback-only netns; any cpu and one cpu)
    python bench/bus.py --secure   # + slots under mTLS and the access policy, router vs peer links
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, TypeVar

import msgspec
import zenoh
from benchlib import pct, write_results

from bbcs import InputSlot, Kind, Module, ModuleContext, OutputSlot, keys
from bbcs.session import SessionConfig, TlsConfig, local_client, open_session, peer_links_config
from bbcs.testing import Processes, child_env, free_port, start_router, wait_port
from module_manager.bus_links import peer_session

SIZES = {"small": 0, "1k": 1000, "32k": 32_000}
MODES = ("raw", "bbcs", "rawpeer", "bbcspeer")
"""Small messages run in all four; 1k/32k only through the router (raw, bbcs)."""
MODE_LABEL = {"raw": "zenoh clients via router", "bbcs": "slot, links = router", "rawpeer": "zenoh peers, direct",
              "bbcspeer": "slot, links = peers", "bbcs_tls": "slot, links = router, mTLS + policy on the router",
              "bbcspeer_tls": "slot, links = peers, mTLS + policy on each receiver"}
ROBOT = "bench"
R = TypeVar("R")
ONE_CPU = max(os.sched_getaffinity(0))
PLACEMENTS = (("", None), ("_1cpu", ONE_CPU))
"""``--peers`` measures each stack (both its processes) twice: wherever the kernel places them, and both on one
processor, as ``cpus = [n]`` in a manifest places two modules (docs/performance.md, "Placing modules on
processors"). Suffix of the measurement's mode, processor (None: the kernel's choice)."""
PLACEMENT_LABEL = {"": "kernel's placement", "_1cpu": f"both on cpu {ONE_CPU}"}


class BenchMsg(msgspec.Struct, frozen=True, kw_only=True):
    """A numbered, range-checked datum; ``body`` stands for a payload (empty: a ~40 B struct)."""

    seq: int
    stamp_ns: int
    value: Annotated[float, msgspec.Meta(ge=-180.0, le=180.0)] = 12.5
    tilt: Annotated[float, msgspec.Meta(ge=-90.0, le=90.0)] = -45.0
    body: bytes = b""


def _cfg(port: int, mode: str = "raw", identity: str = "pinger") -> SessionConfig:
    """Client of the router (``raw``/``bbcs``), or a Zenoh peer linked directly to the other side (``*peer``).

    A peer listens on a free 127.0.0.1 port and connects to the router; the router's gossip tells each peer the
    other's locator, and they link directly (multicast scouting stays off): the topology of ``links = "peers"``.
    ``*_tls``: the same under mutual TLS with ``identity``'s certificate and, for a peer, the robot's access policy
    on its ingress, exactly as ``module_manager/bus_links.py`` configures a module of a ``[bus.tls]`` manifest.
    """
    if mode.endswith("_tls"):
        pki = Path(os.environ[PKI_ENV])
        client = SessionConfig(mode="client", connect=[f"tls/127.0.0.1:{port}"], tls=TlsConfig(
            root_ca=str(pki / "ca.pem"), cert=str(pki / f"{identity}.pem"), key=str(pki / f"{identity}.key")))
        if "peer" not in mode:
            return client
        return peer_session(client, json.loads((pki / PEER_ACL).read_text()))
    if mode.endswith("peer"):
        return peer_links_config(port, free_port())
    return local_client(port)


PKI_ENV, PEER_ACL = "CROMAT_BENCH_PKI", "peer_acl.json"
IDENTITY = {"echo": "echo", "ping": "pinger", "sink": "counter", "blast": "blaster"}
SECURE_MODES = ("bbcs_tls", "bbcspeer_tls")


def start_secure_router(procs: Processes, folder: Path) -> int:
    """Certificates for the bench's four modules (``cromat certs``), the robot router with mTLS and the access
    policy (bbcs/acl.py) on a free port, and the peers' ingress policy for the children (``$CROMAT_BENCH_PKI``)."""
    from cromat import certs
    from module_manager.bus_links import peer_policy
    from module_manager.secure import ROUTER, certificate_cn

    port, pki, cfg = free_port(), folder / "pki", folder / "router.json5"
    if certs.main([str(pki), "--gcs", "gcs", "--modules", ",".join(IDENTITY.values()), "--robot", ROBOT,
                   "--acl", str(cfg), "--listen", f"tls/127.0.0.1:{port}"]) != 0:
        raise SystemExit("cromat certs failed")
    router_cfg = json.loads(cfg.read_text().split("\n", 1)[1])  # after the generated header comment
    (pki / PEER_ACL).write_text(json.dumps(peer_policy(router_cfg["access_control"],
                                                            certificate_cn(pki / f"{ROUTER}.pem"))))
    os.environ[PKI_ENV] = str(pki)
    procs.start(["-m", "bbcs.router", "--config", str(cfg), "--listen", f"tls/127.0.0.1:{port}"],
                stdout=subprocess.DEVNULL)
    wait_port(port)
    return port


# ------------------------------------------------------------------ roles (run in child processes)

class Echo(Module):
    """bbcs pong: every datum received on ``ping`` goes back out on ``pong``."""

    name = "echo"
    slots = (InputSlot("ping", BenchMsg, kind=Kind.STREAM, peer="pinger"),
             OutputSlot("pong", BenchMsg, kind=Kind.STREAM))

    def on_start(self) -> None:
        self._pong = self.output("pong")

    def on_ping(self, msg: BenchMsg) -> None:
        self._pong.publish(msg)


class Pinger(Module):
    """bbcs ping: sends the next ping from the handler of the previous pong; records one-way times."""

    name = "pinger"
    slots = (InputSlot("pong", BenchMsg, kind=Kind.STREAM, peer="echo"),
             OutputSlot("ping", BenchMsg, kind=Kind.STREAM))
    count = 0
    body = b""

    def on_start(self) -> None:
        self.samples: list[float] = []
        self._ping = self.output("ping")
        self.ready = threading.Event()

    def send(self, seq: int) -> None:
        self._ping.publish(BenchMsg(seq=seq, stamp_ns=time.perf_counter_ns(), body=self.body))

    def on_pong(self, msg: BenchMsg) -> None:
        self.samples.append((time.perf_counter_ns() - msg.stamp_ns) / 2000.0)
        if len(self.samples) >= self.count:
            self.request_stop()
        else:
            self.send(msg.seq + 1)


class Counter(Module):
    """bbcs throughput sink: counts every datum handled."""

    name = "counter"
    slots = (InputSlot("data", BenchMsg, kind=Kind.STREAM, peer="blaster", queue=100_000),)
    expected = 0

    def on_start(self) -> None:
        self.n = 0
        self.first = self.last = 0.0

    def on_data(self, msg: BenchMsg) -> None:
        self.n += 1
        if self.n == 1:
            self.first = time.perf_counter()
        if self.n >= self.expected:
            self.last = time.perf_counter()
            self.request_stop()


def _wait_alive(session: zenoh.Session, module: str) -> None:
    seen = threading.Event()
    sub = session.liveliness().declare_subscriber(keys.alive_key(ROBOT, module), lambda s: seen.set(), history=True)
    if not seen.wait(20):
        raise SystemExit(f"{module} never came up")
    sub.undeclare()


def role_main(args: argparse.Namespace) -> None:
    port, body = args.port, b"x" * SIZES[args.size]
    ctx = lambda name: ModuleContext(robot=ROBOT, module=name, bus=_cfg(port, args.mode, name))  # noqa: E731
    raw_ping_key, raw_pong_key = f"bench/{args.tag}/ping", f"bench/{args.tag}/pong"
    qos = {"reliability": zenoh.Reliability.RELIABLE, "congestion_control": zenoh.CongestionControl.BLOCK}
    if args.role == "echo" and args.mode.startswith("bbcs"):
        echo = Echo(ctx("echo"))
        threading.Thread(target=lambda: (sys.stdin.read(), echo.request_stop()), daemon=True).start()
        echo.run()
    elif args.role == "echo":
        s = open_session(_cfg(port, args.mode), module=True)
        pub = s.declare_publisher(raw_pong_key, **qos)
        sub = s.declare_subscriber(raw_ping_key, lambda smp: pub.put(smp.payload.to_bytes()))
        token = s.liveliness().declare_token(keys.alive_key(ROBOT, "echo"))
        sys.stdin.read()
        token.undeclare()
        sub.undeclare()
        s.close()
    elif args.role == "ping" and args.mode.startswith("bbcs"):
        Pinger.count, Pinger.body = args.count, body
        pinger = Pinger(ctx("pinger"))

        def kick() -> None:
            probe = open_session(_cfg(port, "bbcs_tls" if args.mode.endswith("_tls") else "raw"), module=True)
            _wait_alive(probe, "echo")
            _wait_alive(probe, "pinger")
            probe.close()
            time.sleep(0.2)
            with pinger.lock:
                pinger.send(0)

        threading.Thread(target=kick, daemon=True).start()
        pinger.run()
        print(json.dumps(pinger.samples))
    elif args.role == "ping":
        s = open_session(_cfg(port, args.mode), module=True)
        samples: list[float] = []
        done = threading.Event()
        pub = s.declare_publisher(raw_ping_key, **qos)
        dec = msgspec.msgpack.Decoder(BenchMsg).decode

        def on_pong(smp: zenoh.Sample) -> None:
            msg = dec(smp.payload.to_bytes())
            samples.append((time.perf_counter_ns() - msg.stamp_ns) / 2000.0)
            if len(samples) >= args.count:
                done.set()
            else:
                pub.put(msgspec.msgpack.encode(BenchMsg(seq=msg.seq + 1, stamp_ns=time.perf_counter_ns(), body=body)))

        sub = s.declare_subscriber(raw_pong_key, on_pong)
        _wait_alive(s, "echo")
        time.sleep(0.2)
        pub.put(msgspec.msgpack.encode(BenchMsg(seq=0, stamp_ns=time.perf_counter_ns(), body=body)))
        done.wait(120)
        sub.undeclare()
        s.close()
        print(json.dumps(samples))
    elif args.role == "sink" and args.mode.startswith("bbcs"):
        Counter.expected = args.count
        counter = Counter(ctx("counter"))
        counter.run()
        print(json.dumps({"n": counter.n, "seconds": counter.last - counter.first}))
    elif args.role == "sink":
        s = open_session(_cfg(port, args.mode), module=True)
        state = {"n": 0, "first": 0.0, "last": 0.0}
        done = threading.Event()

        def on_data(smp: zenoh.Sample) -> None:
            state["n"] += 1
            if state["n"] == 1:
                state["first"] = time.perf_counter()
            if state["n"] >= args.count:
                state["last"] = time.perf_counter()
                done.set()

        sub = s.declare_subscriber(f"bench/{args.tag}/data", on_data)
        token = s.liveliness().declare_token(keys.alive_key(ROBOT, "counter"))
        done.wait(120)
        token.undeclare()
        sub.undeclare()
        s.close()
        print(json.dumps({"n": state["n"], "seconds": state["last"] - state["first"]}))
    elif args.role == "blast":
        s = open_session(_cfg(port, args.mode, IDENTITY["blast"]), module=True)
        _wait_alive(s, "counter")
        time.sleep(0.2)
        if args.mode.startswith("bbcs"):
            from bbcs.slots import Publisher
            pub = Publisher(s, keys.slot_key(ROBOT, "blaster", "data"), OutputSlot("data", BenchMsg, kind=Kind.STREAM))
            for seq in range(args.count + 1000):
                pub.publish(BenchMsg(seq=seq, stamp_ns=0, body=body))
            pub.close()
        else:
            rpub = s.declare_publisher(f"bench/{args.tag}/data", **qos)
            payload = msgspec.msgpack.encode(BenchMsg(seq=0, stamp_ns=0, body=body))
            for _ in range(args.count + 1000):
                rpub.put(payload)
            rpub.undeclare()
        sys.stdin.read()
        s.close()


def udp_role(args: argparse.Namespace) -> None:
    """The IPC floor: the same ping-pong over a plain UDP socket on 127.0.0.1 (no bus, no router)."""
    import socket

    body = b"x" * SIZES[args.size]
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    if args.role == "udp_echo":
        sock.bind(("127.0.0.1", args.port))
        print("ready", flush=True)
        while True:
            data, peer = sock.recvfrom(65536)
            if data == b"stop":
                break
            sock.sendto(data, peer)
    else:
        samples: list[float] = []
        sock.settimeout(5)
        for seq in range(args.count):
            sock.sendto(msgspec.msgpack.encode(BenchMsg(seq=seq, stamp_ns=time.perf_counter_ns(), body=body)),
                        ("127.0.0.1", args.port))
            msg = msgspec.msgpack.decode(sock.recvfrom(65536)[0], type=BenchMsg)
            samples.append((time.perf_counter_ns() - msg.stamp_ns) / 2000.0)
        sock.sendto(b"stop", ("127.0.0.1", args.port))
        print(json.dumps(samples))
    sock.close()


def udp_latency_run(count: int) -> list[float]:
    from bbcs.testing import free_port

    procs = Processes()
    try:
        port = free_port()
        echo = _child(procs, "--role", "udp_echo", "--port", str(port))
        echo.stdout.readline()
        ping = _child(procs, "--role", "udp_ping", "--port", str(port), "--count", str(count))
        out, _ = ping.communicate(timeout=120)
        echo.wait(10)
        samples = json.loads(out.strip().splitlines()[-1])
        return samples[len(samples) // 10:]
    finally:
        procs.stop_all()


def in_netns(role: str, count: int, cpu: int | None = None) -> object:
    """Run ``--role role`` (which starts both sides of a peer's measurement) inside a fresh loopback-only network
    namespace, so that a peer that binds its sockets on every interface (Cyclone DDS does) still reaches nothing
    but loopback; its JSON result. Without a namespace (not permitted here) the role runs here, confined by its
    own configuration only. ``cpu``: everything the role starts runs on that one processor (:func:`on_cpu`)."""
    from bus_peers import NETNS_SHELL, netns_usable, on_cpu, unshare_argv

    argv = [sys.executable, str(Path(__file__).resolve()), "--role", role, "--count", str(count)]
    if netns_usable() is None:  # usable
        argv = [*unshare_argv(), "sh", "-c", NETNS_SHELL, "netns", *argv]
    out = subprocess.run(argv, capture_output=True, text=True, timeout=300, env=child_env(),
                         preexec_fn=on_cpu(cpu))
    if out.returncode != 0:
        raise SystemExit(f"{role} failed (exit {out.returncode}): {out.stderr[-800:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _own_router(run: Callable[[int], R]) -> R:
    """``run(port)`` with a router of its own on ``port``, stopped afterwards."""
    procs = Processes()
    try:
        return run(start_router(procs))
    finally:
        procs.stop_all()


def netns_slot_throughput(count: int) -> float:
    """Small-slot throughput over peer links with its own router, where the peers' throughput runs."""
    return _own_router(lambda port: throughput_run(port, "bbcspeer", "small", count, "netns"))


def netns_secure_slot_latency(count: int) -> list[float]:
    """``netns_slot_latency`` on a secured robot: mutual TLS on every link, the access policy on the router and at
    each receiving peer (``bbcspeer_tls``), its own certificates and router."""
    procs = Processes()
    with tempfile.TemporaryDirectory(prefix="cromat-bus-") as folder:
        try:
            return latency_run(start_secure_router(procs, Path(folder)), "bbcspeer_tls", "small", count, "netns")
        finally:
            procs.stop_all()


def netns_slot_latency(count: int) -> list[float]:
    """A slot over peer links (``links = "peers"``) with its own router, run where the peers run (their loopback-only
    namespace): the like-for-like basis of the ``peer_*_p50_ratio`` keys (measured here, a fresh namespace's loopback
    was 3-8 % faster than this machine's own, about the gap being judged)."""
    return _own_router(lambda port: latency_run(port, "bbcspeer", "small", count, "netns"))


def dds_latency_run(count: int) -> list[float]:
    from bus_peers import cyclone_env, new_domain

    procs = Processes()
    try:
        env = child_env(**cyclone_env(new_domain()))
        echo = _child(procs, "--role", "dds_echo", "--count", "0", env=env)
        echo.stdout.readline()
        ping = _child(procs, "--role", "dds_ping", "--count", str(count), env=env)
        out, _ = ping.communicate(timeout=180)
        echo.wait(30)
        samples = json.loads(out.strip().splitlines()[-1])
        return samples[len(samples) // 10:]
    finally:
        procs.stop_all()


def dds_throughput_run(count: int) -> float:
    from bus_peers import cyclone_env, new_domain

    procs = Processes()
    try:
        env = child_env(**cyclone_env(new_domain()))
        sink = _child(procs, "--role", "dds_sink", "--count", str(count), env=env)
        sink.stdout.readline()
        blast = _child(procs, "--role", "dds_blast", "--count", str(count), env=env)
        out, _ = sink.communicate(timeout=180)
        blast.stdin.close()
        blast.wait(30)
        res = json.loads(out.strip().splitlines()[-1])
        return (res["n"] - 1) / res["seconds"]
    finally:
        procs.stop_all()


def dora_latency_run(count: int, cpu: int | None = None) -> list[float]:
    from bus_peers import dora_run

    samples = dora_run(("ping", "echo"), count, SIZES["small"], cpu=cpu)
    return samples[len(samples) // 10:]


def dora_throughput_run(count: int, cpu: int | None = None) -> tuple[float, float]:
    """Messages/s at the reader and the share of the sent messages it got (dora's queues drop the oldest)."""
    from bus_peers import dora_run

    res = dora_run(("blast", "sink"), count, SIZES["small"], cpu=cpu)
    return (res["n"] - 1) / res["seconds"] if res["seconds"] > 0 else 0.0, res["n"] / count


# ------------------------------------------------------------------ orchestration

def _child(procs: Processes, *args: str, env: dict[str, str] | None = None) -> subprocess.Popen:
    return procs.start([str(Path(__file__).resolve()), *args], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                       text=True, **({"env": env} if env is not None else {}))


def latency_run(port: int, mode: str, size: str, count: int, tag: str) -> list[float]:
    procs = Processes()
    try:
        base = ["--port", str(port), "--mode", mode, "--size", size, "--tag", tag]
        echo = _child(procs, "--role", "echo", *base)
        ping = _child(procs, "--role", "ping", "--count", str(count), *base)
        out, _ = ping.communicate(timeout=180)
        echo.stdin.close()
        echo.wait(10)
        samples = json.loads(out.strip().splitlines()[-1])
        return samples[len(samples) // 10:]
    finally:
        procs.stop_all()


def throughput_run(port: int, mode: str, size: str, count: int, tag: str) -> float:
    procs = Processes()
    try:
        base = ["--port", str(port), "--mode", mode, "--size", size, "--tag", tag, "--count", str(count)]
        sink = _child(procs, "--role", "sink", *base)
        blast = _child(procs, "--role", "blast", *base)
        out, _ = sink.communicate(timeout=180)
        blast.stdin.close()
        blast.wait(10)
        res = json.loads(out.strip().splitlines()[-1])
        return (res["n"] - 1) / res["seconds"]
    finally:
        procs.stop_all()


PEER_LABEL = {"udp": "IPC floor: UDP ping-pong", "bbcspeer_netns": "slot, links = peers",
              "bbcspeer_tls_netns": "slot, links = peers, mTLS + policy on each receiver",
              "cyclonedds": "Cyclone DDS Python, reliable, keep-all", "dora": "dora-rs 1.1 Python nodes"}


def peer_summary(lat: dict, thr: dict, get: dict, rows: list[dict], summary: dict, notes: dict,
                 why_not: dict[str, str | None]) -> None:
    """The ``--peers`` rows and keys. Every peer figure is compared with a slot over peer links measured the same
    way: in a loopback-only netns, with the same placement of its two processes. The contract keys
    (``peer_*_p50_ratio``: peer p50 over the slot's, above 1 = the slot is faster) are for both processes on one
    processor, the placement a robot gives two modules whose slot must be fast (``cpus``); ``*_any_cpu`` the same
    where the kernel places them."""
    for sfx, _cpu in PLACEMENTS:
        ksfx = "" if sfx else "_any_cpu"
        here = lat[("bbcspeer_netns" + sfx, "small")]
        bbcs_p50, bbcs_rate = pct(here, 50), statistics.median(thr[("bbcspeer_netns" + sfx, "small")])
        summary[f"peer_link_netns{sfx}_p50_us"] = bbcs_p50
        summary[f"ipc_floor{sfx}_p50_us"] = pct(lat[("udp" + sfx, "small")], 50)
        for mode in ("udp", "bbcspeer_netns", "bbcspeer_tls_netns", "cyclonedds", "dora"):
            if (mode + sfx, "small") not in lat and mode not in why_not:
                continue  # the secured slot: only with --secure
            if mode in why_not and why_not[mode] is not None:
                summary[f"peer_{mode}_p50_ratio{ksfx}"] = None  # the contract key; why it has no value: "notes"
                notes[f"peer_{mode}"] = why_not[mode]
                if sfx:
                    print(f"peer {mode}: not measured: {why_not[mode]}")
                continue
            s = lat[(mode + sfx, "small")]
            rate = statistics.median(thr[(mode + sfx, "small")]) if (mode + sfx, "small") in thr else None
            rows.append({"payload": "small", "mode": mode + sfx, "p50_us": pct(s, 50), "p99_us": pct(s, 99),
                         "samples": len(s), "msgs_per_s": rate})
            print(f"{'small':8} {mode + sfx:24} {pct(s, 50):7.1f} {pct(s, 99):9.1f} "
                  f"{'' if rate is None else f'{rate:11,.0f}':11}   ({PEER_LABEL[mode]}, loopback-only netns, "
                  f"{PLACEMENT_LABEL[sfx]})")
            if mode == "bbcspeer_tls_netns":
                summary[f"secure_peer_link_netns{sfx}_p50_us"] = pct(s, 50)
            if mode in why_not:
                summary[f"peer_{mode}_p50_ratio{ksfx}"] = pct(s, 50) / bbcs_p50
                if ("bbcspeer_tls_netns" + sfx, "small") in lat:  # the peer (unsecured) against a secured slot
                    summary[f"secure_peer_{mode}_p50_ratio{ksfx}"] = (
                        pct(s, 50) / pct(lat[("bbcspeer_tls_netns" + sfx, "small")], 50))
                summary[f"peer_{mode}_throughput_ratio{ksfx}"] = (rate or 0.0) / bbcs_rate
                if not sfx:
                    summary[f"peer_{mode}_over_router_p50_ratio"] = pct(s, 50) / get[("bbcs", "small")]["p50_us"]
    notes["bbcs_baseline"] = ("peer_*_p50_ratio / peer_*_throughput_ratio: the peer's p50 (rate) over a slot's over "
                              "peer links, both measured in a fresh loopback-only netns with both processes on one "
                              f"processor (cpu {ONE_CPU}, as a manifest's cpus places two modules; "
                              "peer_link_netns_1cpu_p50_us); *_any_cpu: the same with the kernel placing the "
                              "processes (peer_link_netns_p50_us); *_over_router_*: over a slot through the router "
                              "(outside the netns, the kernel's placement)")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rounds", type=int, default=5, help="interleaved rounds per configuration")
    p.add_argument("--pings", type=int, default=2000)
    p.add_argument("--messages", type=int, default=200_000, help="messages per throughput run (small)")
    p.add_argument("--peers", action="store_true",
                   help="also measure Cyclone DDS, dora-rs (in a loopback-only netns) and the IPC floor (UDP "
                        "ping-pong on 127.0.0.1) in the same run")
    p.add_argument("--secure", action="store_true",
                   help="also measure small slots under mTLS and the access policy, links = router vs peers")
    p.add_argument("--out", help="result file (default bench/results/bus.json)")
    p.add_argument("--smoke", action="store_true",
                   help="one round of 50 pings and 2000 messages (200 of 32 kB, no 1 kB): proves it still runs (CI)")
    p.add_argument("--role", help=argparse.SUPPRESS)
    p.add_argument("--mode", help=argparse.SUPPRESS)
    p.add_argument("--size", default="small", help=argparse.SUPPRESS)
    p.add_argument("--port", type=int, help=argparse.SUPPRESS)
    p.add_argument("--count", type=int, help=argparse.SUPPRESS)
    p.add_argument("--tag", default="t", help=argparse.SUPPRESS)
    args = p.parse_args()
    sizes = tuple(SIZES)
    if args.smoke:  # the 1 kB payload runs the same code as the other two: left out
        args.rounds, args.pings, args.messages = 1, 50, 2000
        sizes = ("small", "32k")
    if args.role in ("udp_echo", "udp_ping"):
        udp_role(args)
        return
    if args.role in ("netns_dds_latency", "netns_dds_throughput"):
        run = dds_latency_run if args.role.endswith("latency") else dds_throughput_run
        print(json.dumps(run(args.count)))
        return
    netns_roles = {"netns_slot_latency": netns_slot_latency, "netns_udp_latency": udp_latency_run,
                   "netns_slot_throughput": netns_slot_throughput,
                   "netns_secure_slot_latency": netns_secure_slot_latency}
    if args.role in netns_roles:
        print(json.dumps(netns_roles[args.role](args.count)))
        return
    if args.role and args.role.startswith("dds_"):
        from bus_peers import cyclone_role
        cyclone_role(args.role[4:], args.count or 0, SIZES[args.size])
        return
    if args.role:
        role_main(args)
        return
    dds_why = dora_why = None
    if args.peers:
        from bus_peers import cyclone_available, dora_available
        dds_why, dora_why = cyclone_available(), dora_available()
    procs = Processes()
    dora_delivered: list[float] = []
    secure_dir = tempfile.TemporaryDirectory(prefix="cromat-bus-") if args.secure else None
    try:
        port = start_router(procs)
        secure_port = start_secure_router(procs, Path(secure_dir.name)) if secure_dir else 0
        lat: dict[tuple[str, str], list[float]] = {}
        thr: dict[tuple[str, str], list[float]] = {}
        for rnd in range(args.rounds):
            for sfx, cpu in PLACEMENTS if args.peers else ():
                lat.setdefault(("udp" + sfx, "small"), []).extend(in_netns("netns_udp_latency", args.pings, cpu))
                lat.setdefault(("bbcspeer_netns" + sfx, "small"), []).extend(
                    in_netns("netns_slot_latency", args.pings, cpu))
                if args.secure:
                    lat.setdefault(("bbcspeer_tls_netns" + sfx, "small"), []).extend(
                        in_netns("netns_secure_slot_latency", args.pings, cpu))
                thr.setdefault(("bbcspeer_netns" + sfx, "small"), []).append(
                    in_netns("netns_slot_throughput", args.messages, cpu))
                if dds_why is None:
                    lat.setdefault(("cyclonedds" + sfx, "small"), []).extend(
                        in_netns("netns_dds_latency", args.pings, cpu))
                    thr.setdefault(("cyclonedds" + sfx, "small"), []).append(
                        in_netns("netns_dds_throughput", args.messages // 10, cpu))
                if dora_why is None:
                    lat.setdefault(("dora" + sfx, "small"), []).extend(dora_latency_run(args.pings, cpu))
                    rate, got = dora_throughput_run(args.messages // 10, cpu)
                    thr.setdefault(("dora" + sfx, "small"), []).append(rate)
                    dora_delivered.append(got)
            for size in sizes:
                for mode in MODES if size == "small" else ("raw", "bbcs"):
                    lat.setdefault((mode, size), []).extend(
                        latency_run(port, mode, size, args.pings, f"l{rnd}{size}{mode}"))
            scans = 200 if args.smoke else max(5000, args.messages // 10)
            for size, count in (("small", args.messages), ("32k", scans)):
                for mode in MODES if size == "small" else ("raw", "bbcs"):
                    thr.setdefault((mode, size), []).append(
                        throughput_run(port, mode, size, count, f"t{rnd}{size}{mode}"))
            for mode in SECURE_MODES if secure_dir else ():
                lat.setdefault((mode, "small"), []).extend(
                    latency_run(secure_port, mode, "small", args.pings, f"l{rnd}{mode}"))
                thr.setdefault((mode, "small"), []).append(
                    throughput_run(secure_port, mode, "small", args.messages, f"t{rnd}{mode}"))
    finally:
        procs.stop_all()
        if secure_dir is not None:
            secure_dir.cleanup()

    rows = []
    print(f"{'payload':8} {'mode':12} {'p50 µs':>9} {'p99 µs':>9} {'msgs/s':>11}")
    for size in sizes:
        for mode in (*MODES, *(SECURE_MODES if args.secure else ())) if size == "small" else ("raw", "bbcs"):
            s = lat[(mode, size)]
            rate = statistics.median(thr[(mode, size)]) if (mode, size) in thr else None
            rows.append({"payload": size, "mode": mode, "p50_us": pct(s, 50), "p99_us": pct(s, 99),
                         "samples": len(s), "msgs_per_s": rate})
            print(f"{size:8} {mode:12} {pct(s, 50):9.1f} {pct(s, 99):9.1f} "
                  f"{'' if rate is None else f'{rate:11,.0f}'}   ({MODE_LABEL[mode]})")
    get = {(r["mode"], r["payload"]): r for r in rows}
    summary = {
        "small_p50_ratio": get[("bbcs", "small")]["p50_us"] / get[("raw", "small")]["p50_us"],
        "small_p99_ratio": get[("bbcs", "small")]["p99_us"] / get[("raw", "small")]["p99_us"],
        "throughput_ratio": get[("bbcs", "small")]["msgs_per_s"] / get[("raw", "small")]["msgs_per_s"],
        "scan_p50_ratio": get[("bbcs", "32k")]["p50_us"] / get[("raw", "32k")]["p50_us"],
        "scan_throughput_ratio": get[("bbcs", "32k")]["msgs_per_s"] / get[("raw", "32k")]["msgs_per_s"],
        # links = "peers": a slot over a direct peer link, against raw zenoh peers (same topology) ...
        "peer_link_small_p50_ratio": get[("bbcspeer", "small")]["p50_us"] / get[("rawpeer", "small")]["p50_us"],
        "peer_link_throughput_ratio": (get[("bbcspeer", "small")]["msgs_per_s"]
                                       / get[("rawpeer", "small")]["msgs_per_s"]),
        # ... and against the same slot through the router (below 1: the peer links are faster)
        "peer_link_over_router_p50": get[("bbcspeer", "small")]["p50_us"] / get[("bbcs", "small")]["p50_us"],
    }
    summary_notes: dict[str, str] = {}
    if args.secure:  # both under mTLS + the access policy: the router's, or each receiving peer's
        summary["secure_peer_link_over_router_p50"] = (get[("bbcspeer_tls", "small")]["p50_us"]
                                                       / get[("bbcs_tls", "small")]["p50_us"])
        summary["secure_peer_link_throughput_ratio"] = (get[("bbcspeer_tls", "small")]["msgs_per_s"]
                                                        / get[("bbcs_tls", "small")]["msgs_per_s"])
    if args.peers:
        peer_summary(lat, thr, get, rows, summary, summary_notes, {"cyclonedds": dds_why, "dora": dora_why})
        if dora_delivered:
            summary["peer_dora_delivered_share"] = min(dora_delivered)
            summary_notes["peer_dora"] = "dora ran in a fresh network namespace with only loopback (unshare -n)"
    print("\n" + "\n".join(f"{k:34} {'n/a' if v is None else f'{v:.3f}'}" for k, v in summary.items()))
    write_results("bus", {"summary": summary, "rows": rows, "notes": summary_notes, "rounds": args.rounds,
                          "pings": args.pings,
                          "messages": args.messages, "stamp": time.time()}, args.out)


if __name__ == "__main__":
    main()
