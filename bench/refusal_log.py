"""What ``cromat router --log-refusals`` (on by default on a secure launch) costs on allowed traffic.

With the flag, Zenoh's access-control target logs at TRACE, a line for every message it checks, allowed ones
included, and the router reads those lines back through a pipe (bbcs/router_audit.py). This benchmark runs the
same secure router (mTLS + the generated policy, certificates made at run time) with and without the flag, in
alternating rounds of the same run: the module identity ``vision`` publishes ``--messages`` small messages
(64 bytes, congestion control BLOCK, so none is dropped) on its own slot, the ``gcs`` identity receives them all.
Per round it measures the delivery rate and the router's CPU time per message (``/proc/<pid>/stat``).

    python bench/refusal_log.py [--messages 5000] [--rounds 3]

Writes bench/results/refusal_log.json with summary keys ``rate_off_msgs_s``, ``rate_on_msgs_s``,
``rate_ratio`` (on / off; 1 = free), ``router_cpu_us_per_msg_off`` and ``router_cpu_us_per_msg_on``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from statistics import median

import zenoh
from benchlib import ROOT, write_results

from bbcs import SessionConfig, TlsConfig, open_session
from bbcs.testing import free_port, wait_port
from cromat import certs

ROBOT = "uav1"
KEY = f"cromat/{ROBOT}/vision/bench"
TICKS = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of ``pid`` so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def client(pki: Path, name: str, port: int) -> SessionConfig:
    folder = pki.with_name(pki.name + "-ground") if name == "gcs" else pki
    tls = TlsConfig(root_ca=str(pki / "ca.pem"), cert=str(folder / f"{name}.pem"), key=str(folder / f"{name}.key"),
                    mtls=True)
    return SessionConfig(connect=[f"tls/localhost:{port}"], tls=tls, connect_timeout_s=20.0)


def one_round(cfg: Path, pki: Path, log_refusals: bool, messages: int) -> dict[str, float]:
    port = free_port()
    argv = [sys.executable, "-m", "bbcs.router", "--config", str(cfg), "--listen", f"tls/127.0.0.1:{port}"]
    router = subprocess.Popen(argv + (["--log-refusals"] if log_refusals else []), cwd=str(ROOT),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_port(port)
        got = [0]
        done = threading.Event()

        def on(_sample: zenoh.Sample) -> None:
            got[0] += 1
            if got[0] >= messages:
                done.set()

        sub_s, pub_s = open_session(client(pki, "gcs", port)), open_session(client(pki, "vision", port))
        try:
            sub = sub_s.declare_subscriber(KEY, on)
            pub = pub_s.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
            warm = threading.Event()
            probe = sub_s.declare_subscriber(KEY + "_ready", lambda _s: warm.set())
            while not warm.is_set():  # the route exists end to end before timing
                pub_s.put(KEY + "_ready", b"x")
                warm.wait(0.1)
            probe.undeclare()
            payload = bytes(64)
            cpu0, t0 = cpu_s(router.pid), time.perf_counter()
            for _ in range(messages):
                pub.put(payload)
            if not done.wait(120):
                raise RuntimeError(f"only {got[0]} of {messages} messages arrived")
            elapsed, cpu = time.perf_counter() - t0, cpu_s(router.pid) - cpu0
            pub.undeclare()
            sub.undeclare()
        finally:
            pub_s.close()
            sub_s.close()
        return {"rate_msgs_s": messages / elapsed, "router_cpu_us_per_msg": 1e6 * cpu / messages}
    finally:
        router.terminate()
        router.wait(20)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--messages", type=int, default=5000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", help="result file (default bench/results/refusal_log.json)")
    ap.add_argument("--smoke", action="store_true", help="200 messages, one round: proves it runs (CI)")
    args = ap.parse_args(argv)
    if args.smoke:
        args.messages, args.rounds = 200, 1
    with tempfile.TemporaryDirectory(prefix="cromat-bench-refusals-") as tmp:
        pki, cfg = Path(tmp) / "pki", Path(tmp) / "router.json5"
        assert certs.main([str(pki), "--gcs", "gcs", "--modules", "vision", "--robot", ROBOT, "--acl", str(cfg),
                           "--listen", "tls/127.0.0.1:7447"]) == 0
        rounds: dict[str, list[dict[str, float]]] = {"off": [], "on": []}
        for i in range(args.rounds):
            for mode in ("off", "on") if i % 2 == 0 else ("on", "off"):  # alternate: load drift hits both
                rounds[mode].append(one_round(cfg, pki, mode == "on", args.messages))
    med = {mode: {k: median(r[k] for r in rs) for k in rs[0]} for mode, rs in rounds.items()}
    print(f"{'router':<22}{'msgs/s':>12}{'router CPU us/msg':>20}")
    for mode in ("off", "on"):
        print(f"{'--log-refusals ' + mode:<22}{med[mode]['rate_msgs_s']:>12.0f}"
              f"{med[mode]['router_cpu_us_per_msg']:>20.1f}")
    summary = {
        "rate_off_msgs_s": round(med["off"]["rate_msgs_s"]),
        "rate_on_msgs_s": round(med["on"]["rate_msgs_s"]),
        "rate_ratio": round(med["on"]["rate_msgs_s"] / med["off"]["rate_msgs_s"], 3),
        "router_cpu_us_per_msg_off": round(med["off"]["router_cpu_us_per_msg"], 1),
        "router_cpu_us_per_msg_on": round(med["on"]["router_cpu_us_per_msg"], 1),
    }
    write_results("refusal_log", {"summary": summary, "messages": args.messages, "rounds": rounds,
                                  "load_average": os.getloadavg()}, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
