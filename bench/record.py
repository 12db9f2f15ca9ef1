"""Recorder benchmark: what ``cromat record`` sustains against the bus's own rate, and its CPU cost on the UAV.

1. **Throughput**, same run, same router, same publisher: a child process publishes ``RobotTelemetry`` structs
   (safe stream: reliable, BLOCK) on 4 keys as fast as it can. First a subscriber that only counts (the bus's
   own rate, the baseline), then the recorder (Zenoh callback → queue → writer thread → MCAP, zstd) for the same
   time; its rate counts every message written, the drain after the stop included.
2. **CPU share on the simulated UAV**: ``cromat launch bbcs_conf/uav1_sim.toml``, then ``cromat record --robot
   uav1`` (everything, full rate) as a child process; CPU time (user+sys, from wait4) over wall time. The same
   command recording a key nobody publishes is the start-up/idle baseline, measured in the same run.

    python bench/record.py            # defaults: ~1 minute; table on stdout, JSON in bench/results/record.json
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

from benchlib import ROOT, write_results

from bbcs import Kind, OutputSlot, Publisher, keys, local_client, open_session
from bbcs.contracts.geo import Attitude, GeoPoint, VelocityNED
from bbcs.contracts.robot import RobotTelemetry
from bbcs.testing import Processes, child_env, start_router

KEYS = 4
ROBOT = "bench"


def sample(i: int) -> RobotTelemetry:
    return RobotTelemetry(stamp=time.time(), position=GeoPoint(lat=37.41 + i * 1e-7, lon=-6.0, alt=30.0 + i % 7),
                          attitude=Attitude(roll=1.0, pitch=-2.0, yaw=93.5), velocity=VelocityNED(vn=3.0, ve=4.0,
                          vd=-0.5), heading_deg=93.5, mode=2, mode_name="AUTOMATIC", tracking=True, path_valid=True,
                          airborne=True, waypoints_queued=12, pan_deg=10.0, tilt_deg=-30.0, pan_tilt_mode=0,
                          error_code=0)


def publisher(port: int, seconds: float) -> int:
    """Child role: publish as fast as possible for ``seconds``; prints the count."""
    session = open_session(local_client(port))
    pubs = [Publisher(session, keys.slot_key(ROBOT, f"m{k}", "telemetry"),
                      OutputSlot("telemetry", RobotTelemetry, kind=Kind.STREAM)) for k in range(KEYS)]
    payloads = [sample(i) for i in range(64)]
    time.sleep(0.5)  # let the subscriber's declaration reach this session (a fixed lead-in, not a measurement)
    end = time.monotonic() + seconds
    n = 0
    while time.monotonic() < end:
        for _ in range(100):
            pubs[n % KEYS].publish(payloads[n % 64])
            n += 1
    for p in pubs:
        p.close()
    session.close()
    print(n, flush=True)
    return 0


def run_publisher(port: int, seconds: float) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, __file__, "--role", "publisher", "--port", str(port),
                             "--seconds", str(seconds)], env=child_env(), cwd=str(ROOT), stdout=subprocess.PIPE,
                            text=True)


def drain(received, published: int, quiet_s: float = 2.0) -> None:
    """Wait for what is still in flight: until all arrived, or nothing more arrived for ``quiet_s``."""
    last, still = -1, time.monotonic()
    while received() < published and time.monotonic() - still < quiet_s:
        if received() != last:
            last, still = received(), time.monotonic()
        time.sleep(0.05)


def baseline(port: int, seconds: float) -> dict[str, float]:
    session = open_session(local_client(port))
    count = [0, 0]
    lock = threading.Lock()

    def on_sample(s) -> None:
        with lock:
            count[0] += 1
            count[1] += len(s.payload)

    sub = session.declare_subscriber(keys.slot_pattern(ROBOT), on_sample)
    pub = run_publisher(port, seconds)
    t0 = time.monotonic()
    published = int(pub.communicate()[0].strip() or 0)
    drain(lambda: count[0], published)
    wall = time.monotonic() - t0 - 0.5
    sub.undeclare()
    session.close()
    return {"published": published, "received": count[0], "msgs_per_s": count[0] / wall,
            "mb_per_s": count[1] / wall / 1e6}


def recorder(port: int, seconds: float, out: Path) -> dict[str, float]:
    from cromat.tools.catalog import Catalog
    from cromat.tools.record import McapSink, Recorder

    session = open_session(local_client(port))
    sink = McapSink(out, Catalog(), split=False)
    cpu0 = time.process_time()
    rec = Recorder(session, sink, [keys.slot_pattern(ROBOT)])
    pub = run_publisher(port, seconds)
    t0 = time.monotonic()
    published = int(pub.communicate()[0].strip() or 0)
    drain(lambda: rec.received, published)
    summary = rec.stop()
    wall = time.monotonic() - t0 - 0.5
    cpu = time.process_time() - cpu0
    session.close()
    return {"published": published, "recorded": summary.messages, "missed": summary.missed,
            "msgs_per_s": summary.messages / wall, "mb_per_s": summary.bytes / wall / 1e6,
            "file_mb": out.stat().st_size / 1e6, "cpu_share": cpu / wall, "cpu_s": cpu,
            "msgs_per_cpu_s": summary.messages / max(cpu, 1e-9)}


def record_child(endpoint: str, seconds: float, args: list[str], out: Path) -> dict[str, float]:
    """Run ``cromat record`` for ``seconds``; its CPU time over wall time (from wait4)."""
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "cromat", "record", "--connect", endpoint, "-o", str(out),
                             "--duration", str(seconds), *args], env=child_env(), cwd=str(ROOT),
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    text = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"cromat record failed ({proc.returncode}): {text}")
    first = text.splitlines()[0]
    return {"cpu_s": usage.ru_utime + usage.ru_stime, "wall_s": wall, "messages": int(first.split()[1]),
            "cpu_share": (usage.ru_utime + usage.ru_stime) / wall}


def uav_cpu(seconds: float, tmp: Path) -> tuple[dict[str, float], dict[str, float]]:
    sys.path.insert(0, str(ROOT / "tests" / "module_manager"))
    from launch_support import Launch

    la = Launch(ROOT / "bbcs_conf" / "uav1_sim.toml", tmp)
    try:
        la.wait_line("all 6 modules up", 90)
        endpoint = f"tcp/127.0.0.1:{la.port}"
        idle = record_child(endpoint, seconds, ["--select", "uav1/nobody/publishes"], tmp / "idle.mcap")
        full = record_child(endpoint, seconds, ["--robot", "uav1"], tmp / "uav.mcap")
    finally:
        la.stop()
        la.cleanup()
    return idle, full


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--role", default="bench")
    p.add_argument("--port", type=int, default=0)
    p.add_argument("--seconds", type=float, default=3.0, help="throughput phase length")
    p.add_argument("--uav-seconds", type=float, default=15.0, help="UAV recording length")
    p.add_argument("--out", help="results file (default bench/results/record.json)")
    p.add_argument("--smoke", action="store_true", help="0.5 s phases, 1 s of UAV recording: proves it runs (CI)")
    args = p.parse_args()
    if args.smoke:
        args.seconds, args.uav_seconds = 0.5, 1.0
    if args.role == "publisher":
        return publisher(args.port, args.seconds)
    procs = Processes()
    with tempfile.TemporaryDirectory(prefix="cromat-bench-record-") as d:
        tmp = Path(d)
        try:
            port = start_router(procs)
            base = baseline(port, args.seconds)
            rec = recorder(port, args.seconds, tmp / "throughput.mcap")
        finally:
            procs.stop_all()
        idle, full = uav_cpu(args.uav_seconds, tmp)
    rows = [
        ("bus alone: counting subscriber", f"{base['msgs_per_s']:,.0f} msg/s", f"{base['mb_per_s']:.2f} MB/s",
         f"{base['received']}/{base['published']} received"),
        ("recorder (MCAP, zstd)", f"{rec['msgs_per_s']:,.0f} msg/s", f"{rec['mb_per_s']:.2f} MB/s",
         f"{rec['recorded']}/{rec['published']} recorded, {rec['missed']} missed, "
         f"{rec['msgs_per_cpu_s']:,.0f} msg per CPU-s"),
        ("UAV sim, record idle (start-up)", f"{idle['messages']} msgs", f"CPU {idle['cpu_s']:.2f} s",
         f"{idle['cpu_share']:.1%} of a core over {idle['wall_s']:.1f} s"),
        ("UAV sim, record everything", f"{full['messages']} msgs", f"CPU {full['cpu_s']:.2f} s",
         f"{full['cpu_share']:.1%} of a core over {full['wall_s']:.1f} s"),
    ]
    for row in rows:
        print(f"{row[0]:<34} {row[1]:>16} {row[2]:>14}  {row[3]}")
    write_results("record", {
        "summary": {"record_msgs_per_s": round(rec["msgs_per_s"]), "record_mb_per_s": round(rec["mb_per_s"], 3),
                    "record_msgs_per_cpu_s": round(rec["msgs_per_cpu_s"]),
                    "bus_msgs_per_s": round(base["msgs_per_s"]), "record_vs_bus": round(
                        rec["msgs_per_s"] / base["msgs_per_s"], 3),
                    "record_cpu_share_uav": round(full["cpu_share"], 4),
                    "record_cpu_share_uav_idle": round(idle["cpu_share"], 4)},
        "baseline": base, "recorder": rec, "uav_idle": idle, "uav_full": full,
    }, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
