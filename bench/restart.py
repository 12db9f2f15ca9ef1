"""Restart of a SIGKILLed module against a cold start of the same module, in the same run.

The probe robot of the module-manager tests runs under ``cromat launch`` (two sources publishing every 5 ms, a
sink routed to one of them) with ``standby = true``: the manager keeps a warm standby of each module (its imports
done, module_manager/standby.py) that becomes the module at a restart. Each kill SIGKILLs the sink once its
standby is warm (the steady state of a running robot) and times, from the kill: its liveliness back (alive), its
RouteAck from the new run (routes restored), and the first datum it handled (the ``t`` the sink stamps on its
record). A cold start stops the sink through the MRI (a stopped module has no standby), then starts it again and
times the same first datum from the start request. The intensity window is set short (``period_s``) and kills
are spaced past it, so each kill is a first failure, restarted with no backoff (see docs/manifest.md).
``--no-standby`` measures restarts without a standby (the cold-start path, the figure before standbys).

    python bench/restart.py [--kills 50] [--colds 10] [--no-standby]

Writes bench/results/restart.json with summary keys ``restart_p50_ms``, ``restart_p99_ms``, ``cold_p50_ms`` and
``restart_ratio`` (restart p50 over cold start p50; target ≤ 1), and ``standby``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

import msgspec
from benchlib import ROOT, pct, write_results

from bbcs import RouteAck, SessionConfig, keys, open_session
from bbcs.contracts import mri

sys.path.insert(0, str(ROOT / "tests" / "module_manager"))
from launch_support import Launch, standbys, write_manifest  # noqa: E402

ROBOT, MODULE = "r1", "sink"
PERIOD_S = 0.3


class Events:
    """Wall-clock times of the sink's liveliness PUTs and RouteAcks, as they arrive."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.alive: list[float] = []
        self.acks: list[float] = []
        self._decode = msgspec.msgpack.Decoder(RouteAck).decode

    def on_alive(self, sample) -> None:
        if str(sample.kind).endswith("PUT"):
            with self.lock:
                self.alive.append(time.time())

    def on_ack(self, sample) -> None:
        ack = self._decode(sample.payload.to_bytes())
        if ack.accepted:
            with self.lock:
                self.acks.append(time.time())

    def first_after(self, which: str, t0: float) -> float | None:
        with self.lock:
            return next((t for t in getattr(self, which) if t > t0), None)


def records(path: Path, offset: int) -> tuple[list[dict], int]:
    """Complete JSON lines of the sink's record from byte ``offset``."""
    with path.open("rb") as f:
        f.seek(offset)
        data = f.read()
    end = data.rfind(b"\n") + 1
    rows = [json.loads(line) for line in data[:end].splitlines() if line.strip()]
    return rows, offset + end


def first_datum_after_start(path: Path, offset: int, deadline_s: float = 30.0) -> float:
    """Wall time the sink stamped on its first datum after its next ``start`` record."""
    end = time.monotonic() + deadline_s
    started = False
    while time.monotonic() < end:
        rows, offset = records(path, offset)
        for row in rows:
            if row.get("event") == "start":
                started = True
            elif started and row.get("slot") == "datos":
                return float(row["t"])
        time.sleep(0.005)
    raise SystemExit("the sink handled no datum after its start")


def wait_warm(manager_pid: int, deadline_s: float = 60.0) -> None:
    """Until the manager's standby of the sink is warm: imports done, blocked reading its context."""
    end = time.monotonic() + deadline_s
    while not any(standbys(manager_pid, "mm_sink").values()):
        if time.monotonic() > end:
            raise SystemExit("no warm standby of the sink")
        time.sleep(0.02)


def sink_status(session) -> mri.ModuleStatus:
    reply = mri.call(session, ROBOT, "modules", mri.ListModules(), 20.0)
    assert isinstance(reply.data, mri.ModuleList)
    return next(m for m in reply.data.modules if m.name == MODULE)


def wait_up(session, other_than: int | None, deadline_s: float = 30.0) -> int:
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        st = sink_status(session)
        if st.state == "up" and st.pid is not None and st.pid != other_than:
            return st.pid
        time.sleep(0.02)
    raise SystemExit(f"the sink is not up again: {sink_status(session)}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=50)
    ap.add_argument("--colds", type=int, default=10)
    ap.add_argument("--no-standby", action="store_true",
                    help="restart without a warm standby (the same path as a cold start; for comparison)")
    ap.add_argument("--out", help="result file (default bench/results/restart.json)")
    ap.add_argument("--smoke", action="store_true", help="2 kills, 1 cold start: proves the bench still runs (CI)")
    args = ap.parse_args(argv)
    if args.smoke:
        args.kills, args.colds = 2, 1
    tmp = Path(tempfile.mkdtemp(prefix="cromat-bench-restart-"))
    standby = "false" if args.no_standby else "true"
    manifest = write_manifest(tmp, edit=lambda t: t.replace(
        "period_s = 30.0", f"period_s = {PERIOD_S}\nstandby = {standby}"))
    record = tmp / "sink.jsonl"
    la = Launch(manifest, tmp)
    events = Events()
    session = None
    entities = []
    restart = {"alive": [], "routes": [], "datum": []}
    cold: list[float] = []
    try:
        la.wait_line("all 3 modules up", 60)
        session = open_session(SessionConfig(mode="client", connect=[f"tcp/127.0.0.1:{la.port}"]))
        entities.append(session.liveliness().declare_subscriber(keys.alive_key(ROBOT, MODULE), events.on_alive))
        entities.append(session.declare_subscriber(keys.route_ack_key(ROBOT, MODULE), events.on_ack))
        pid = wait_up(session, None)
        cold_every = max(1, args.kills // max(1, args.colds))
        for i in range(args.kills):
            time.sleep(PERIOD_S + 0.05)  # past the intensity window: a first failure, restarted at once
            if not args.no_standby:
                wait_warm(la.proc.pid)  # the steady state of a running robot: its standby is ready
            offset = record.stat().st_size
            t0 = time.time()
            os.kill(pid, signal.SIGKILL)
            datum = first_datum_after_start(record, offset)
            alive, acked = events.first_after("alive", t0), events.first_after("acks", t0)
            restart["datum"].append((datum - t0) * 1000)
            restart["alive"].append(((alive or datum) - t0) * 1000)
            restart["routes"].append(((acked or datum) - t0) * 1000)
            pid = wait_up(session, pid)
            if len(cold) < args.colds and i % cold_every == cold_every - 1:
                stop = mri.call(session, ROBOT, "module", mri.ModuleCommand(module=MODULE, action="stop"), 30.0)
                assert stop.ok, stop.reason
                offset = record.stat().st_size
                t0 = time.time()
                start = mri.call(session, ROBOT, "module", mri.ModuleCommand(module=MODULE, action="start"), 30.0)
                assert start.ok, start.reason
                cold.append((first_datum_after_start(record, offset) - t0) * 1000)
                pid = wait_up(session, pid)
    finally:
        for e in entities:
            e.undeclare()
        if session is not None:
            session.close()
        if la.proc.poll() is None:
            la.stop()
        la.cleanup()
        shutil.rmtree(tmp, ignore_errors=True)
    r50, r99, c50 = pct(restart["datum"], 50), pct(restart["datum"], 99), pct(cold, 50)
    ratio = r50 / c50
    print(f"{'measure (ms from kill / start request)':<44} {'p50':>8} {'p99':>8} {'n':>4}")
    for name, values in (("restart: alive again", restart["alive"]), ("restart: routes acknowledged",
                                                                      restart["routes"]),
                         ("restart: first datum handled", restart["datum"]), ("cold start: first datum handled",
                                                                               cold)):
        print(f"{name:<44} {pct(values, 50):8.1f} {pct(values, 99):8.1f} {len(values):4d}")
    print(f"restart_ratio {ratio:.2f} (restart p50 over cold start p50)")
    write_results("restart", {
        "kills": args.kills, "colds": len(cold), "restart_alive_ms": restart["alive"],
        "restart_routes_ms": restart["routes"], "restart_datum_ms": restart["datum"], "cold_datum_ms": cold,
        "summary": {"restart_p50_ms": round(r50, 1), "restart_p99_ms": round(r99, 1), "cold_p50_ms": round(c50, 1),
                    "cold_p99_ms": round(pct(cold, 99), 1),
                    "restart_ratio": round(ratio, 3), "standby": not args.no_standby}}, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
