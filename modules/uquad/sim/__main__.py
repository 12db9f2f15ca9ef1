"""``python -m modules.uquad.sim --conf bbcs_conf/uquad1.conf --imu 127.0.0.1:0 --esc 127.0.0.1:0 ...``"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

from modules.uquad.calibration import load_calibration
from modules.uquad.config import load_config
from modules.uquad.geo import Home
from modules.uquad.sim.quad import QuadSim
from modules.uquad.sim.server import PtyEnd, SimServer, TcpEnd


def _tcp(name: str, spec: str) -> TcpEnd:
    host, _, port = spec.rpartition(":")
    return TcpEnd(name, host or "127.0.0.1", int(port))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m modules.uquad.sim", description=__doc__)
    ap.add_argument("--conf", required=True, help="robot .conf (QUAD group, HOME_*, IMU_CALIB_FILE, IMU_MODE)")
    ap.add_argument("--imu", default="127.0.0.1:0", help="host:port, or 'pty'")
    ap.add_argument("--gps", default="127.0.0.1:0", help="host:port, 'pty', or 'none'")
    ap.add_argument("--esc", default="127.0.0.1:0", help="host:port")
    ap.add_argument("--truth", default="127.0.0.1:0", help="host:port or 'none'")
    ap.add_argument("--control", default="none",
                    help="host:port of the fault-injection port (JSON lines, modules/uquad/sim/server.py) or 'none'")
    ap.add_argument("--imu-mode", choices=("binary", "ascii"), default=None, help="override IMU_MODE of the .conf")
    ap.add_argument("--speed", type=float, default=1.0,
                    help="simulated seconds per wall second (in lockstep the most it may go; inf: as fast as answered)")
    ap.add_argument("--lockstep", action="store_true",
                    help="step only once the ESC set-point computed from the last IMU frame has arrived (run the "
                         "motor driver with --lockstep and the flight module with clock = imu)")
    ap.add_argument("--answer-timeout", type=float, default=0.5,
                    help="lockstep: wall seconds to wait for a set-point before stepping on with the last one (0.5)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=None, help="simulated seconds, then exit")
    args = ap.parse_args(argv)
    if not args.speed > 0:
        ap.error(f"--speed must be above 0, not {args.speed:g}")
    if not args.answer_timeout > 0:
        ap.error(f"--answer-timeout must be above 0, not {args.answer_timeout:g}")
    cfg = load_config(Path(args.conf))
    sim = QuadSim(params=cfg.quad, calib=load_calibration(cfg.imu_calib_file),
                  home=Home(cfg.home_lat, cfg.home_lon, cfg.home_alt), seed=args.seed)
    imu = PtyEnd("imu") if args.imu == "pty" else _tcp("imu", args.imu)
    gps = None if args.gps == "none" else PtyEnd("gps") if args.gps == "pty" else _tcp("gps", args.gps)
    truth = None if args.truth == "none" else _tcp("truth", args.truth)
    control = None if args.control == "none" else _tcp("control", args.control)
    server = SimServer(sim, imu, gps, _tcp("esc", args.esc), truth, imu_mode=args.imu_mode or cfg.imu_mode,
                       speed=args.speed, control=control, lockstep=args.lockstep,
                       answer_every=cfg.values.CONTROL_EVERY, answer_timeout_s=args.answer_timeout)
    signal.signal(signal.SIGTERM, lambda *_: server.stop())
    signal.signal(signal.SIGINT, lambda *_: server.stop())
    parts = " ".join(f"{e.name}={e.url}" for e in server.ends())
    print(f"uquad sim ready {parts}", flush=True)
    try:
        server.run(args.duration)
    finally:
        server.close()
        s = server.stats
        print(f"uquad sim stopped t={sim.t:.2f} imu_frames={s.imu_frames} imu_bytes_lost={s.imu_bytes_lost} "
              f"esc_frames={s.esc_frames} esc_timeouts={s.esc_timeouts} lockstep_waits={s.lockstep_waits} "
              f"lockstep_timeouts={s.lockstep_timeouts}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
