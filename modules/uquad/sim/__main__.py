"""``python -m modules.uquad.sim --conf bbcs_conf/uquad1.conf --imu 127.0.0.1:0 --esc 127.0.0.1:0 ...``

Started by a lockstep launch (``CROMAT_SIM`` in its environment, docs/simulation.md) it is the robot's stepper:
it joins the robot's bus before its readiness line and steps on the barrier (modules/uquad/sim/server.py), with
the device links' lockstep on whether or not ``--lockstep`` is given.
"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

from bbcs import SessionConfig, open_session
from bbcs.lockstep import Stepper, settings_from_env
from modules.uquad.calibration import load_calibration
from modules.uquad.config import load_config
from modules.uquad.geo import Home
from modules.uquad.sim.lockstep import lockstep_speed
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
                    help="simulated seconds per wall second (in lockstep the most it may go; inf: as fast as answered; "
                         "on the bus barrier the launch's speed wins when it gives one)")
    ap.add_argument("--lockstep", action="store_true",
                    help="step only once the ESC set-point computed from the last IMU frame has arrived (run the "
                         "motor driver with --lockstep and the flight module with clock = imu)")
    ap.add_argument("--answer-timeout", type=float, default=None,
                    help="lockstep: wall seconds to wait for a set-point before stepping on with the last one (0.5; "
                         "on the bus barrier the launch's deadline_s)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=None, help="simulated seconds, then exit")
    args = ap.parse_args(argv)
    if not args.speed > 0:
        ap.error(f"--speed must be above 0, not {args.speed:g}")
    if args.answer_timeout is not None and not args.answer_timeout > 0:
        ap.error(f"--answer-timeout must be above 0, not {args.answer_timeout:g}")
    try:
        settings = settings_from_env()
    except ValueError as exc:
        ap.error(str(exc))
    if settings is not None and settings.fleet:
        ap.error("a uQuad in a lockstep fleet ([sim] fleet) is not built: its simulator steps its own robot "
                 "only (docs/simulation.md)")
    cfg = load_config(Path(args.conf))
    sim = QuadSim(params=cfg.quad, calib=load_calibration(cfg.imu_calib_file),
                  home=Home(cfg.home_lat, cfg.home_lon, cfg.home_alt), seed=args.seed)
    imu = PtyEnd("imu") if args.imu == "pty" else _tcp("imu", args.imu)
    gps = None if args.gps == "none" else PtyEnd("gps") if args.gps == "pty" else _tcp("gps", args.gps)
    truth = None if args.truth == "none" else _tcp("truth", args.truth)
    control = None if args.control == "none" else _tcp("control", args.control)
    server = SimServer(sim, imu, gps, _tcp("esc", args.esc), truth, imu_mode=args.imu_mode or cfg.imu_mode,
                       speed=args.speed, control=control, lockstep=args.lockstep,
                       answer_every=cfg.values.CONTROL_EVERY,
                       answer_timeout_s=0.5 if args.answer_timeout is None else args.answer_timeout)
    signal.signal(signal.SIGTERM, lambda *_: server.stop())
    signal.signal(signal.SIGINT, lambda *_: server.stop())
    session = stepper = None
    if settings is not None:  # before the readiness line: a module starting asks the stepper the time (@clock)
        session = open_session(SessionConfig(mode="client", connect=settings.connect))
        stepper = Stepper(session, settings.robot, deadline_s=settings.deadline_s)
        server.use_stepper(stepper, settings.step_s, lockstep_speed(settings.speed, args.speed),
                           settings.deadline_s if args.answer_timeout is None else args.answer_timeout)
    parts = " ".join(f"{e.name}={e.url}" for e in server.ends())
    print(f"uquad sim ready {parts}", flush=True)
    try:
        server.run(args.duration)
    finally:
        server.close()
        if stepper is not None:
            stepper.close()
        if session is not None:
            session.close()
        s = server.stats
        print(f"uquad sim stopped t={sim.t:.2f} imu_frames={s.imu_frames} imu_bytes_lost={s.imu_bytes_lost} "
              f"esc_frames={s.esc_frames} esc_timeouts={s.esc_timeouts} lockstep_waits={s.lockstep_waits} "
              f"lockstep_timeouts={s.lockstep_timeouts}", flush=True)
        if stepper is not None:
            wall = server.wall_s
            print(f"uquad sim lockstep: {stepper.step} steps, {stepper.rounds} rounds, {sim.t:.1f} s simulated in "
                  f"{wall:.1f} s of wall ({sim.t / wall if wall > 0 else 0.0:.2f}x)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
