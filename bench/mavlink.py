"""The MAVLink gateway's cost: command → DSP latency through ``cromat mavlink`` against the GCS API (what ``cromat
gcs`` runs) in the same run, and the gateway's CPU for ten robots at full telemetry.

1. Latency. The simulated UAV (bbcs_conf/uav1_sim.toml, the real Module Manager, the DSP simulator recording) and a
   gateway process on its router. Rounds alternate: a pymavlink ground station sends ``DO_MOUNT_CONTROL`` to the
   gateway (→ a ``pan_tilt`` task), then the GCS Python API sends the same task itself; each with angles of its own.
   Latency = from the send to the simulator's record of that ``SET_PT_ANGLES`` (its ``mono`` stamp: CLOCK_MONOTONIC,
   comparable across processes). ``mavlink_cmd_ratio`` = gateway p50 / GCS p50 (target ≤ 1.5).
2. CPU. A router, ten robots' GRI states published on it at the RAL's default rate (5 Hz, full telemetry: position,
   attitude, velocity, battery, pan & tilt, a running task, six modules), a gateway serving all ten (``--all``) to a
   pymavlink ground station on UDP at QGroundControl's rates. ``mavlink_cpu_share_10`` = the gateway process's CPU
   seconds (/proc utime + stime) over a window / the window (target < 0.15 of one core).

    python bench/mavlink.py [--rounds 30] [--window 20] [--smoke]

Writes bench/results/mavlink.json (summary keys ``mavlink_cmd_ratio``, ``mavlink_cpu_share_10``) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from benchlib import ROOT, pct, stop_group, work_dir, write_results

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from bbcs import (
    SessionConfig,
    open_session,
    wire,  # noqa: E402
)
from bbcs.contracts import gri  # noqa: E402
from bbcs.contracts.geo import Attitude, GeoPoint, VelocityNED  # noqa: E402
from bbcs.contracts.mri import ModuleStatus  # noqa: E402
from bbcs.contracts.robot import RobotTelemetry  # noqa: E402
from bbcs.contracts.tasks import TaskInfo  # noqa: E402
from bbcs.testing import free_port  # noqa: E402
from ral.gcs.api import Gcs, session_config  # noqa: E402

ROBOT = "uav1"
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "CROMAT_LOG": "WARNING"}


class Proc:
    """A child in its own session, every output line kept; stopped with its group."""

    def __init__(self, *args: str) -> None:
        self.lines: list[str] = []
        self.proc = subprocess.Popen([sys.executable, *args], cwd=str(ROOT), env=ENV, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, start_new_session=True)
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())

    def wait_line(self, text: str, timeout_s: float) -> None:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if any(text in x for x in self.lines):
                return
            if self.proc.poll() is not None:
                break
            time.sleep(0.05)
        raise RuntimeError(f"no {text!r} from {self.proc.args}:\n" + "\n".join(self.lines[-20:]))

    def cpu_s(self) -> float:
        fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rpartition(")")[2].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def stop(self) -> None:
        stop_group(self.proc)


class Record:
    """The DSP simulator's record, read as it grows."""

    def __init__(self, path: Path) -> None:
        self.path, self.offset, self.pending = path, 0, ""

    def wait_angles(self, pan: float, after: float, timeout_s: float = 10.0) -> float:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.path.exists():
                with self.path.open() as f:
                    f.seek(self.offset)
                    self.pending += f.read()
                    self.offset = f.tell()
                *lines, self.pending = self.pending.split("\n")
                for line in lines:
                    rec = json.loads(line)
                    if rec["name"] == "SET_PT_ANGLES" and rec["mono"] >= after \
                            and abs(rec["fields"]["pan_deg"] - pan) < 0.01:
                        return float(rec["mono"])
            time.sleep(0.001)
        raise RuntimeError(f"no SET_PT_ANGLES pan {pan} in the DSP simulator's record")


def manifest(work: Path) -> tuple[Path, Path]:
    record = work / "dsp_record.jsonl"
    text = (ROOT / "bbcs_conf" / "uav1_sim.toml").read_text()
    text = text.replace('conf = "uav1.conf"', f'conf = "{ROOT / "bbcs_conf" / "uav1.conf"}"')
    old = '"--tcp", "127.0.0.1:{port:dsp}"]'
    assert old in text, "the DSP simulator's command line in uav1_sim.toml changed"
    text = text.replace(old, f'"--tcp", "127.0.0.1:{{port:dsp}}", "--record", "{record}"]')
    path = work / "uav1_sim.toml"
    path.write_text(text)
    return path, record


def latency(work: Path, rounds: int, failed: dict[str, list[str]]) -> dict[str, list[float]]:
    """Latency samples per path; ``failed`` gets each round that was refused or never reached the DSP."""
    man, record_path = manifest(work)
    port, tcp = free_port(), free_port()
    launch = Proc("-m", "module_manager.cli", str(man), "--listen", f"tcp/127.0.0.1:{port}", "--log-dir",
                  str(work / "logs"))
    gw = gcs = conn = None
    try:
        launch.wait_line("modules up", 120)
        gw = Proc("-m", "cromat", "mavlink", "--connect", f"tcp/127.0.0.1:{port}", "--tcp", str(tcp), "--robot",
                  f"{ROBOT}=1")
        gw.wait_line(f"robot {ROBOT} is MAVLink system 1", 60)
        gcs = Gcs(session_config([f"tcp/127.0.0.1:{port}"]), name="bench", timeout_s=10.0)
        conn = mavutil.mavlink_connection(f"tcp:127.0.0.1:{tcp}", source_system=250, source_component=190,
                                          dialect="common", autoreconnect=False)
        conn.wait_heartbeat(timeout=20)
        record = Record(record_path)
        out: dict[str, list[float]] = {"mavlink": [], "gcs": []}
        for i in range(rounds + 1):  # the first round warms both paths up and is not counted
            for path in ("mavlink", "gcs"):
                pan = round(-170.0 + (2 * i + (path == "gcs")) * 0.5, 1) % 340 - 170
                t0 = time.monotonic()
                try:
                    if path == "mavlink":
                        conn.mav.command_long_send(1, 1, 205, 0, -10.0, 0.0, pan, 0.0, 0.0, 0.0, 2.0)
                    else:
                        reply = gcs.send(ROBOT, gri.SetPanTilt(pan=pan, tilt=-10.0))
                        if not reply.accepted:
                            raise RuntimeError(reply.reason)
                    at = record.wait_angles(pan, t0)
                except RuntimeError as exc:  # refused or lost under load: no latency sample, counted
                    failed[path].append(str(exc))
                    continue
                if i >= 1:
                    out[path].append((at - t0) * 1000)
                time.sleep(0.05)
        return out
    finally:
        if conn is not None:
            conn.close()
        if gcs is not None:
            gcs.close()
        if gw is not None:
            gw.stop()
        launch.stop()


def robot_state(robot: str, i: int, t: float) -> gri.GriState:
    lat, lon = 37.4117 + 0.001 * i, -6.0025 + 0.0001 * (t % 100)
    tel = RobotTelemetry(stamp=t, position=GeoPoint(lat=lat, lon=lon, alt=40.0),
                         attitude=Attitude(roll=1.0, pitch=-2.0, yaw=(t * 10) % 360),
                         velocity=VelocityNED(vn=3.0, ve=1.0, vd=0.0), heading_deg=(t * 10) % 360, mode=0,
                         airborne=True, waypoints_queued=5, pan_deg=10.0, tilt_deg=-20.0, battery_v=23.0)
    task = TaskInfo(id=1, name="follow_path", task_type="movement", kind="follow_path", started=t)
    modules = [ModuleStatus(name=n, state="up") for n in ("dsp", "telemetry", "pan_tilt", "path_follower", "vision",
                                                          "ral")]
    return gri.GriState(robot=robot, kind="uav", stamp=t, telemetry=tel, home=GeoPoint(lat=lat, lon=lon, alt=12.0),
                        tasks=[task], available={"take_off": "movement", "pan_tilt": "pan_tilt"}, modules=modules,
                        link="up", manager_up=True)


def cpu_share(work: Path, robots: int, window_s: float) -> dict[str, float]:
    port = free_port()
    router = Proc("-m", "cromat", "router", "--listen", f"tcp/127.0.0.1:{port}")
    gw = session = None
    stop = threading.Event()
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    sink.settimeout(0.2)
    received = [0]
    try:
        time.sleep(1.0)
        session = open_session(SessionConfig(mode="client", connect=[f"tcp/127.0.0.1:{port}"]))
        names = [f"bench{i:02d}" for i in range(1, robots + 1)]
        pubs = {n: session.declare_publisher(gri.state_key(n), encoding=wire.encoding_for(gri.GriState))
                for n in names}

        def publish() -> None:
            while not stop.is_set():
                t = time.time()
                for i, n in enumerate(names):
                    pubs[n].put(gri.encode(robot_state(n, i, t)))
                stop.wait(0.2)

        def drain() -> None:
            """QGroundControl's side: reads every frame and sends its ground station's HEARTBEAT each second to
            the gateway (which then holds the ten robots' GRI links, as with an operator connected)."""
            qgc = mavutil.mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
            beat = qgc.heartbeat_encode(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                        mavutil.mavlink.MAV_STATE_ACTIVE)
            next_beat = 0.0
            while not stop.is_set():
                try:
                    data, addr = sink.recvfrom(65536)
                except OSError:
                    continue
                received[0] += len(data) > 0
                if time.monotonic() >= next_beat:
                    next_beat = time.monotonic() + 1.0
                    sink.sendto(beat.pack(qgc), addr)

        threading.Thread(target=publish, daemon=True).start()
        threading.Thread(target=drain, daemon=True).start()
        gw = Proc("-m", "cromat", "mavlink", "--connect", f"tcp/127.0.0.1:{port}", "--all", "--udp",
                  f"127.0.0.1:{sink.getsockname()[1]}")
        for n in names:
            gw.wait_line(f"robot {n} is MAVLink system", 60)
        for n in names:
            gw.wait_line(f"link to {n} held", 30)
        time.sleep(min(2.0, window_s))
        c0, f0, t0 = gw.cpu_s(), received[0], time.monotonic()
        time.sleep(window_s)
        c1, f1, t1 = gw.cpu_s(), received[0], time.monotonic()
        return {"cpu_s": c1 - c0, "window_s": t1 - t0, "frames_per_s": (f1 - f0) / (t1 - t0)}
    finally:
        stop.set()
        if gw is not None:
            gw.stop()
        if session is not None:
            session.close()
        sink.close()
        router.stop()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=30, help="latency rounds (each: one gateway, one GCS command)")
    ap.add_argument("--robots", type=int, default=10)
    ap.add_argument("--window", type=float, default=20.0, help="seconds of CPU measured")
    ap.add_argument("--out", help="result file (default bench/results/mavlink.json)")
    ap.add_argument("--smoke", action="store_true", help="2 rounds, a 2 s window: proves it runs (CI)")
    args = ap.parse_args(argv)
    if args.smoke:
        args.rounds, args.window = 2, 2.0
    with work_dir("cromat-mavlink-") as work:
        return run(args, work)


def run(args: argparse.Namespace, work: Path) -> int:
    """The benchmark in ``work`` (removed when it ends well, kept with its logs when it fails)."""
    started = time.monotonic()
    failed: dict[str, list[str]] = {"mavlink": [], "gcs": []}
    lat = latency(work, args.rounds, failed)
    cpu = cpu_share(work, args.robots, args.window)
    mav50, gcs50 = pct(lat["mavlink"], 50), pct(lat["gcs"], 50)
    share = cpu["cpu_s"] / cpu["window_s"]
    rows = [("command -> DSP through the gateway", lat["mavlink"]), ("command -> DSP through the GCS API", lat["gcs"])]
    print(f"{'path':<38} {'n':>4} {'lost':>4} {'p50 ms':>8} {'p90 ms':>8} {'max ms':>8}")
    for (name, values), key in zip(rows, ("mavlink", "gcs"), strict=True):
        print(f"{name:<38} {len(values):>4} {len(failed[key]):>4} {pct(values, 50):>8.1f} {pct(values, 90):>8.1f} "
              f"{max(values):>8.1f}")
    for key, reasons in failed.items():
        for reason in reasons[:3]:
            print(f"  lost ({key}): {reason}")
    print(f"mavlink_cmd_ratio (p50 gateway / p50 GCS)  {mav50 / gcs50:.2f}   (target <= 1.5)")
    print(f"gateway CPU, {args.robots} robots at full telemetry: {cpu['cpu_s']:.2f} s in {cpu['window_s']:.1f} s = "
          f"{share:.3f} of one core (target < 0.15); {cpu['frames_per_s']:.0f} MAVLink frames/s sent")
    print(f"load average at the end: {os.getloadavg()[0]:.1f}; took {time.monotonic() - started:.0f} s")
    write_results("mavlink", {
        "summary": {"mavlink_cmd_ratio": round(mav50 / gcs50, 3), "mavlink_cpu_share_10": round(share, 4)},
        "latency_ms": {k: {"p50": pct(v, 50), "p90": pct(v, 90), "max": max(v), "n": len(v)} for k, v in lat.items()},
        "lost": {k: len(v) for k, v in failed.items()},
        "cpu": {**cpu, "robots": args.robots},
        "load_average": os.getloadavg()[0], "smoke": args.smoke,
    }, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
