"""Abort latency: from a ground station's ``abort`` request to the simulated DSP's waypoint queue being empty.

Launches the whole simulated UAV (bbcs_conf/uav1_sim.toml through the real Module Manager: router, DSP
simulator, DSP, telemetry, pan & tilt, path follower, vision, RAL) and, from a GCS (Python API, TCP on
127.0.0.1), repeats: follow a 10-waypoint path, wait until the DSP telemetry shows waypoints queued (mid-
path), abort. The queue empties when the simulator handles the ABORT frame; that instant is the simulator's
``--record`` timestamp (CLOCK_MONOTONIC, comparable across processes). The first DSP telemetry showing an
empty queue (100 Hz here) is reported too. Baseline in the same run: the round trip of a no-op MRI request
(``tasks``) from the same GCS session, and of a GRI task request the RAL rejects (no manager call, no DSP).

    python bench/abort.py [--aborts 100]

Each round also replaces the path mid-flight by a new movement task (``goto``): from that request to the
simulator's record showing the new path alone in its queue (its INVALIDATE_PATH, then its last ADD_WAYPOINT).

Writes bench/results/abort.json with summary keys ``abort_p50_ms``, ``abort_p99_ms`` and ``replace_p99_ms``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgspec
from benchlib import ROOT, pct, stop_group, work_dir, write_results

from bbcs import keys
from bbcs.contracts import dsp as p
from bbcs.contracts import gri, mri
from bbcs.testing import free_port
from ral.gcs.api import Gcs, session_config

ROBOT = "uav1"
GRID_DEG = 1e-4  # the DSP carries waypoint lat/lon in 10^-4 degrees


def prepare(work: Path, telemetry_ms: int) -> tuple[Path, Path]:
    """A copy of uav1_sim.toml and uav1.conf: DSP telemetry every ``telemetry_ms``, the simulator
    recording."""
    conf = (ROOT / "bbcs_conf" / "uav1.conf").read_text()
    conf, n = re.subn(
        r"^TELEMETRY_PERIOD_MS:\s*\d+", f"TELEMETRY_PERIOD_MS: {telemetry_ms}", conf, flags=re.M
    )
    assert n == 1, "TELEMETRY_PERIOD_MS not found in uav1.conf"
    (work / "uav1.conf").write_text(conf)
    record = work / "dsp_record.jsonl"
    text = (ROOT / "bbcs_conf" / "uav1_sim.toml").read_text()
    old = '"--tcp", "127.0.0.1:{port:dsp}"]'
    assert old in text, "the DSP simulator's command line in uav1_sim.toml changed"
    text = text.replace(old, f'"--tcp", "127.0.0.1:{{port:dsp}}", "--record", "{record}"]')
    manifest = work / "uav1_sim.toml"
    manifest.write_text(text)
    return manifest, record


class Launch:
    """``cromat launch`` in its own session; stopped (and its group killed) on exit."""

    def __init__(self, manifest: Path, port: int, log_dir: Path) -> None:
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "module_manager.cli",
                str(manifest),
                "--listen",
                f"tcp/127.0.0.1:{port}",
                "--log-dir",
                str(log_dir),
            ],
            cwd=str(ROOT),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
        )

    def wait_up(self, timeout_s: float = 90.0) -> None:
        assert self.proc.stdout is not None
        end = time.monotonic() + timeout_s
        lines = []
        for line in self.proc.stdout:
            if "modules up" in line:
                threading.Thread(target=self._drain, daemon=True).start()
                return
            lines.append(line.rstrip())
            if time.monotonic() > end:
                break
        raise RuntimeError("cromat launch did not bring every module up:\n" + "\n".join(lines[-10:]))

    def _drain(self) -> None:
        assert self.proc.stdout is not None
        for _ in self.proc.stdout:
            pass

    def stop(self) -> None:
        stop_group(self.proc)


class DspWatch:
    """The DSP telemetry's queue length, with the monotonic time each sample arrived."""

    def __init__(self, gcs: Gcs) -> None:
        self.cond = threading.Condition()
        self.samples: list[tuple[float, int]] = []
        self.position: tuple[float, float, float] | None = None
        decode = msgspec.msgpack.Decoder(p.Telemetry).decode

        def on_sample(sample) -> None:  # type: ignore[no-untyped-def]
            t = time.monotonic()
            tel = decode(sample.payload.to_bytes())
            with self.cond:
                if tel.position is not None:
                    self.position = (tel.position.lat, tel.position.lon, tel.position.alt)
                if tel.status is not None:
                    self.samples.append((t, tel.status.queue_length))
                    del self.samples[:-2000]
                    self.cond.notify_all()

        self.sub = gcs.session.declare_subscriber(keys.slot_key(ROBOT, "dsp", "telemetry"), on_sample)

    def wait(self, pred, after: float, timeout_s: float = 5.0) -> float:  # type: ignore[no-untyped-def]
        """Arrival time of the first sample after ``after`` whose queue length satisfies ``pred``."""
        end = time.monotonic() + timeout_s
        with self.cond:
            while True:
                for t, q in self.samples:
                    if t >= after and pred(q):
                        return t
                left = end - time.monotonic()
                if left <= 0:
                    raise RuntimeError("DSP telemetry did not show the expected queue length")
                self.cond.wait(left)

    def close(self) -> None:
        self.sub.undeclare()


class Record:
    """Reads the simulator's command record incrementally."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.offset = 0
        self.pending = ""

    def _new_records(self) -> list[dict]:
        """The records the simulator completed since the last call (a line still being written waits)."""
        if not self.path.exists():
            return []
        with self.path.open() as f:
            f.seek(self.offset)
            chunk = f.read()
            self.offset = f.tell()
        self.pending += chunk
        *lines, self.pending = self.pending.split("\n")
        return [json.loads(line) for line in lines]

    def wait_abort(self, after: float, timeout_s: float = 5.0) -> float:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            for rec in self._new_records():
                if rec["name"] == "ABORT" and rec["mono"] >= after:
                    return float(rec["mono"])
            time.sleep(0.001)
        raise RuntimeError("no ABORT in the DSP simulator's record")

    def wait_replaced(self, after: float, n_points: int, timeout_s: float = 10.0) -> float:
        """When the DSP queue held only the new path: its INVALIDATE_PATH (after ``after``), then its
        ``n_points``-th ADD_WAYPOINT handled."""
        end = time.monotonic() + timeout_s
        cleared = False
        added = 0
        while time.monotonic() < end:
            for rec in self._new_records():
                if rec["mono"] < after:
                    continue
                if rec["name"] == "INVALIDATE_PATH":
                    cleared, added = True, 0
                elif rec["name"] == "ADD_WAYPOINT" and cleared:
                    added += 1
                    if added == n_points:
                        return float(rec["mono"])
            time.sleep(0.001)
        raise RuntimeError("the new path never replaced the old one in the DSP simulator's record")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--aborts", type=int, default=100)
    ap.add_argument("--telemetry-ms", type=int, default=10, help="DSP telemetry period (simulated ms)")
    ap.add_argument("--baseline", type=int, default=200, help="no-op round trips for the baseline")
    ap.add_argument("--out", help="result file (default bench/results/abort.json)")
    ap.add_argument("--smoke", action="store_true", help="2 aborts, 5 baseline round trips: proves it runs (CI)")
    args = ap.parse_args(argv)
    if args.smoke:
        args.aborts, args.baseline = 2, 5
    with work_dir("cromat-abort-") as work:
        return run(args, work)


def run(args: argparse.Namespace, work: Path) -> int:
    """The benchmark in ``work`` (removed when it ends well, kept with its logs when it fails)."""
    manifest, record_path = prepare(work, args.telemetry_ms)
    port = free_port()
    launch = Launch(manifest, port, work / "logs")
    gcs = watch = None
    try:
        launch.wait_up()
        gcs = Gcs(session_config([f"tcp/127.0.0.1:{port}"]), name="bench", link=[ROBOT], timeout_s=10.0)
        watch = DspWatch(gcs)
        t_end = time.monotonic() + 20
        while watch.position is None and time.monotonic() < t_end:
            time.sleep(0.05)
        if watch.position is None:
            raise RuntimeError("no DSP telemetry")
        # the RAL admits a path only once it knows the take-off point (from the telemetry the manager folds in,
        # later than the DSP's own): on a loaded machine the first path came before it and was refused
        states: list[gri.GriState] = []
        gcs.watch(ROBOT, states.append)
        t_end = time.monotonic() + 60
        while not (states and states[-1].home is not None) and time.monotonic() < t_end:
            time.sleep(0.05)
        if not states or states[-1].home is None:
            raise RuntimeError("the RAL does not know the take-off point: no GRI state with a home in 60 s")
        # a path is flown from the air (the RAL refuses it on the ground): take off, until the take-off is done
        reply = gcs.send(ROBOT, gri.TakeOff(height=10.0))
        if not reply.accepted:
            raise RuntimeError(f"take-off rejected: {reply.reason}")
        t_end = time.monotonic() + 120
        while not (states and states[-1].airborne and not any(x.kind == "take_off" for x in states[-1].tasks)):
            if time.monotonic() > t_end:
                raise RuntimeError("not airborne with the take-off done within 120 s")
            time.sleep(0.05)
        lat0 = round(watch.position[0] / GRID_DEG) * GRID_DEG
        lon0 = round(watch.position[1] / GRID_DEG) * GRID_DEG
        alt = watch.position[2] + 20.0
        path = [
            gri.Waypoint(lat=round(lat0 + 20 * GRID_DEG * (i + 1), 4), lon=round(lon0, 4), alt=alt)
            for i in range(10)
        ]
        wait_list = gri.FollowPath(waypoints=path, speed=5.0)
        other = gri.Goto(waypoints=[gri.Waypoint(lat=w.lat, lon=round(w.lon + 5 * GRID_DEG, 4), alt=w.alt)
                                    for w in path], speed=5.0)
        record = Record(record_path)

        # baseline: no-op MRI request and a GRI request the RAL rejects, same session
        mri_rt, gri_rt = [], []
        bad = gri.Cancel(task_type="no_such_type")
        for _ in range(args.baseline):
            t = time.perf_counter()
            mri.call(gcs.session, ROBOT, "tasks", mri.ListTasks())
            mri_rt.append((time.perf_counter() - t) * 1000)
            t = time.perf_counter()
            assert not gcs.send(ROBOT, bad).accepted
            gri_rt.append((time.perf_counter() - t) * 1000)

        to_dsp, to_telemetry, reply_rt, replace = [], [], [], []
        for i in range(args.aborts):
            t_task = time.monotonic()
            reply = gcs.send(ROBOT, wait_list)
            if not reply.accepted:
                raise RuntimeError(f"path task rejected: {reply.reason}")
            watch.wait(lambda q: q > 0, t_task, 15.0)
            # replace: a new movement task mid-path, until the DSP queue holds only the new path
            t0 = time.monotonic()
            reply = gcs.send(ROBOT, other)
            if not reply.accepted:
                raise RuntimeError(f"replacing path rejected: {reply.reason}")
            replace.append((record.wait_replaced(t0, len(other.waypoints)) - t0) * 1000)
            time.sleep(0.02 + 0.03 * (i % 5) / 4)  # abort at varying moments of the flight
            t0 = time.monotonic()
            reply = gcs.abort(ROBOT)
            reply_rt.append((time.monotonic() - t0) * 1000)
            if not reply.accepted:
                raise RuntimeError(f"abort refused: {reply.reason}")
            to_dsp.append((record.wait_abort(t0) - t0) * 1000)
            to_telemetry.append((watch.wait(lambda q: q == 0, t0) - t0) * 1000)
    finally:
        if watch is not None:
            watch.close()
        if gcs is not None:
            gcs.close()
        launch.stop()

    rows = [
        ("abort → DSP queue empty (sim record)", to_dsp),
        ("abort → empty queue in DSP telemetry", to_telemetry),
        ("abort request round trip (GCS reply)", reply_rt),
        ("new movement task → DSP holds only it", replace),
        ("baseline: MRI 'tasks' round trip", mri_rt),
        ("baseline: GRI rejected-task round trip", gri_rt),
    ]
    print(
        f"abort latency, {args.aborts} aborts mid-path, loopback; DSP telemetry every {args.telemetry_ms} ms"
    )
    print(f"{'measure':<42} {'n':>5} {'p50 ms':>9} {'p99 ms':>9} {'max ms':>9}")
    for name, values in rows:
        print(
            f"{name:<42} {len(values):>5} {pct(values, 50):>9.2f} {pct(values, 99):>9.2f} {max(values):>9.2f}"
        )
    p50, p99 = pct(to_dsp, 50), pct(to_dsp, 99)
    print(
        f"abort p50 {p50:.2f} ms, p99 {p99:.2f} ms (target p99 < 50 ms); "
        f"p50 = {p50 / pct(mri_rt, 50):.1f} x the MRI round trip"
    )
    print(f"replace p99 {pct(replace, 99):.2f} ms (target < 100 ms)")
    write_results(
        "abort",
        {
            "bench": "abort",
            "aborts": args.aborts,
            "telemetry_period_ms": args.telemetry_ms,
            "rows": {
                name: {
                    "n": len(v),
                    "p50_ms": round(pct(v, 50), 3),
                    "p99_ms": round(pct(v, 99), 3),
                    "max_ms": round(max(v), 3),
                }
                for name, v in rows
            },
            "summary": {
                "abort_p50_ms": round(p50, 3),
                "abort_p99_ms": round(p99, 3),
                "replace_p99_ms": round(pct(replace, 99), 3),
            },
        },
        args.out,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
