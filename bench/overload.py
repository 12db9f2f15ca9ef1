"""Overload: abort and telemetry on a secured DSP link, quiet, under floods from module identities, and under CPU load.

A robot router with the generated policy (certificates from ``cromat certs`` in a temporary folder), the DSP
simulator and the real DSP process, all on 127.0.0.1. Four phases, measured in the same run:

* quiet;
* ``flood``: the pan & tilt identity puts valid ``SetPanTiltAngles`` batches on its own DSP command key as fast as
  one Python process can (a flooder process, counted), issue 32 case 1;
* ``flood_own_slot``: the vision identity floods ``vision/target``, its own slot, which the ground station's
  session (the telemetry observer) also receives, case 2;
* ``cpu``: 4 busy processes on the machine's cores, case 3.

In each: ``--aborts`` aborts from the path follower's identity (its real output declaration: priority, express),
latency from the put to the ABORT in the simulator's record (CLOCK_MONOTONIC, one clock for the host), and the
longest gap between DSP telemetry samples at a ground-station subscriber. Every flood is bounded (``--seconds``)
and stops by itself; everything stops at the end, on failure too.

    python bench/overload.py [--aborts 20] [--seconds 8]

Writes bench/results/overload.json with summary keys ``abort_p99_ms_flood``, ``abort_p99_ms_cpu``,
``telemetry_max_gap_ms_flood``, ``dsp_restarts`` and their quiet twins (``abort_p99_ms_quiet``,
``telemetry_max_gap_ms_quiet``).
"""

from __future__ import annotations

import argparse
import json
import os
import select
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import msgspec
from benchlib import ROOT, pct, write_results

from bbcs import Publisher, SessionConfig, TlsConfig, open_session
from bbcs.contracts import dsp as bus
from bbcs.contracts import dsp as p
from bbcs.dsp_client import commands_output
from bbcs.testing import Processes, free_port, wait_port, wait_until
from cromat import certs
from modules.dsp.sim.record import read_record

ROBOT = "uav1"
R = f"cromat/{ROBOT}"
FLOODER = """
import sys, time
import msgspec
from bbcs.session import SessionConfig, open_session
cfg = msgspec.json.decode(sys.argv[1], type=SessionConfig)
key, kind, seconds = sys.argv[2], sys.argv[3], float(sys.argv[4])
s = open_session(cfg)
pub = s.declare_publisher(key)
from bbcs.contracts import dsp as bus
from bbcs.contracts.pan_tilt import DatosPT
from bbcs.contracts import dsp as p
n, end = 0, time.monotonic() + seconds
while time.monotonic() < end:
    value = (bus.DspCommands(sender="pan_tilt", batch_id=n, commands=[p.SetPanTiltAngles(pan_deg=n % 90, tilt_deg=-10)])
             if kind == "dsp" else DatosPT(ref_pan=n % 90, ref_tilt=-10))
    pub.put(msgspec.msgpack.encode(value))
    n += 1
print(n, flush=True)
pub.undeclare()
s.close()
"""


def config(pki: Path, port: int, name: str) -> SessionConfig:
    folder = pki.with_name(pki.name + "-ground") if name == "gcs" else pki
    return SessionConfig(connect=[f"tls/localhost:{port}"], tls=TlsConfig(
        root_ca=str(folder / "ca.pem"), cert=str(folder / f"{name}.pem"), key=str(folder / f"{name}.key")))


class Telemetry:
    """Arrival times of DSP telemetry at a ground-station session."""

    def __init__(self, session: object) -> None:
        self.t: list[float] = []
        self.lock = threading.Lock()
        self.sub = session.declare_subscriber(f"{R}/dsp/telemetry", self._on)  # type: ignore[attr-defined]

    def _on(self, _sample: object) -> None:
        with self.lock:
            self.t.append(time.monotonic())

    def max_gap_ms(self, start: float, end: float) -> float:
        with self.lock:
            ts = [t for t in self.t if start <= t <= end]
        return max((b - a for a, b in zip(ts, ts[1:], strict=False)), default=float("inf")) * 1000


def aborts(abort: Publisher, record: Path, n: int, spacing_s: float) -> list[float]:
    """``n`` aborts, each once the previous one is at the simulator; latencies in ms."""
    out = []
    for _ in range(n):
        before = sum(c["name"] == "ABORT" for c in read_record(record))
        asked = time.monotonic()
        abort.publish(bus.DspCommands(sender="path_follower", commands=[p.Abort()]))
        deadline = asked + 30
        while time.monotonic() < deadline:
            got = [c for c in read_record(record) if c["name"] == "ABORT"]
            if len(got) > before:
                out.append((got[before]["mono"] - asked) * 1000)
                break
            time.sleep(0.002)
        else:
            out.append(30_000.0)
        time.sleep(spacing_s)
    return out


DSP_NICE = -5
"""The shipped manifests' ``nice`` for the DSP process (set here on every thread once it runs)."""


def renice(pid: int, nice: int) -> int | None:
    """Every thread of ``pid`` to ``nice`` (what a manifest's ``nice`` does before exec); None if refused."""
    try:
        for task in Path(f"/proc/{pid}/task").iterdir():
            os.setpriority(os.PRIO_PROCESS, int(task.name), nice)
    except OSError as exc:
        print(f"DSP process: nice {nice} refused ({exc.strerror}): measured at the default")
        return None
    return nice


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--aborts", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=8.0, help="length of each loaded phase (floods stop then)")
    ap.add_argument("--out", help="result file (default bench/results/overload.json)")
    ap.add_argument("--smoke", action="store_true", help="3 aborts and 1 s phases: the suite's check that it runs")
    args = ap.parse_args(argv)
    if args.smoke:
        args.aborts, args.seconds = 3, 1.0
    procs = Processes()
    busy: list[subprocess.Popen] = []
    sessions: list[object] = []
    phases: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory(prefix="overload-") as tmp_:
        tmp = Path(tmp_)
        port = free_port()
        pki, cfg = tmp / "robot", tmp / "router.json5"
        assert certs.main([str(pki), "--gcs", "gcs", "--modules", "dsp,pan_tilt,path_follower,vision", "--robot",
                           ROBOT, "--acl", str(cfg), "--listen", f"tls/127.0.0.1:{port}"]) == 0
        # as the shipped uav1_secure.toml: vision's write_hz (its target at 50 puts/s, cut at the router)
        router_cfg = json.loads("\n".join(ln for ln in cfg.read_text().splitlines() if not ln.startswith("//")))
        router_cfg["downsampling"][0]["rules"].append({"key_expr": f"{R}/vision/target", "freq": 50.0})
        cfg.write_text(json.dumps(router_cfg))
        record = tmp / "dsp.jsonl"
        try:
            procs.start(["-m", "bbcs.router", "--config", str(cfg), "--listen", f"tls/127.0.0.1:{port}"],
                        stdout=subprocess.DEVNULL)
            wait_port(port)
            sim = procs.start(["-m", "modules.dsp.sim", "--pty", "--record", str(record)], stdout=subprocess.PIPE,
                              text=True)
            assert select.select([sim.stdout], [], [], 15.0)[0], "the simulator printed nothing"
            pty = sim.stdout.readline().strip()
            dsp = procs.start(["-m", "modules.dsp", "--robot", ROBOT, "--bus",
                               msgspec.json.encode(config(pki, port, "dsp")).decode(), "--conf",
                               str(ROOT / "bbcs_conf" / "uav1.conf"), "--param", f"port={pty}"],
                              stderr=subprocess.DEVNULL)
            gcs = open_session(config(pki, port, "gcs"))
            follower = open_session(config(pki, port, "path_follower"))
            sessions += [gcs, follower]
            telemetry = Telemetry(gcs)
            wait_until(lambda: len(telemetry.t) > 10, 60, "DSP telemetry at the ground station")
            nice = renice(dsp.pid, DSP_NICE)
            abort = Publisher(follower, f"{R}/dsp/{bus.commands_slot('path_follower')}",
                              commands_output("path_follower"))
            time.sleep(1.0)
            spacing = max(0.05, args.seconds / max(1, args.aborts) - 0.05)

            def phase(name: str, load: list[subprocess.Popen]) -> None:
                start = time.monotonic()
                lat = aborts(abort, record, args.aborts, spacing)
                end = time.monotonic()
                rates = []
                for proc in load:
                    if proc.stdout is not None:
                        out, _ = proc.communicate(timeout=args.seconds + 30)
                        rates.append(int(out.strip() or 0) / args.seconds)
                    else:
                        proc.kill()
                        proc.wait()
                phases[name] = {"abort_p50_ms": pct(lat, 50), "abort_p99_ms": pct(lat, 99), "abort_max_ms": max(lat),
                                "telemetry_max_gap_ms": telemetry.max_gap_ms(start, end),
                                **({"flood_per_s": sum(rates)} if rates else {})}

            def flooder(identity: str, key: str, kind: str) -> subprocess.Popen:
                return subprocess.Popen([sys.executable, "-c", FLOODER,
                                         msgspec.json.encode(config(pki, port, identity)).decode(), key, kind,
                                         str(args.seconds)], stdout=subprocess.PIPE, text=True,
                                        env={**os.environ, "PYTHONPATH": str(ROOT)})

            phase("quiet", [])
            phase("flood", [flooder("pan_tilt", f"{R}/dsp/{bus.commands_slot('pan_tilt')}", "dsp")])
            phase("flood_own_slot", [flooder("vision", f"{R}/vision/target", "target")])
            busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(4)]
            phase("cpu", busy)
            busy = []
            restarts = 0 if dsp.poll() is None else 1
        finally:
            for b in busy:
                b.kill()
            for s in sessions:
                s.close()  # type: ignore[attr-defined]
            procs.stop_all()
    summary = {
        "abort_p99_ms_quiet": round(phases["quiet"]["abort_p99_ms"], 1),
        "abort_p99_ms_flood": round(max(phases["flood"]["abort_p99_ms"], phases["flood_own_slot"]["abort_p99_ms"]), 1),
        "abort_p99_ms_cpu": round(phases["cpu"]["abort_p99_ms"], 1),
        "telemetry_max_gap_ms_quiet": round(phases["quiet"]["telemetry_max_gap_ms"], 1),
        "telemetry_max_gap_ms_flood": round(max(phases["flood"]["telemetry_max_gap_ms"],
                                                phases["flood_own_slot"]["telemetry_max_gap_ms"]), 1),
        "dsp_restarts": restarts,
        "dsp_nice": nice,
    }
    print(f"{'phase':16} {'abort p50':>10} {'p99':>8} {'max':>8} {'telemetry gap':>14} {'flood/s':>9}")
    for name, ph in phases.items():
        print(f"{name:16} {ph['abort_p50_ms']:9.1f}ms {ph['abort_p99_ms']:7.1f}ms {ph['abort_max_ms']:7.1f}ms "
              f"{ph['telemetry_max_gap_ms']:12.1f}ms {ph.get('flood_per_s', 0):9.0f}")
    print(f"DSP process exits during the run: {restarts}; load average {os.getloadavg()[0]:.0f}")
    path = write_results("overload", {"summary": summary, "phases": phases, "aborts_per_phase": args.aborts,
                                      "phase_s": args.seconds, "load_average": os.getloadavg()[0]}, args.out)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
