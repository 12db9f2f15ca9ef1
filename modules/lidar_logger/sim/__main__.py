"""Run both simulators as one process (they share the world and its clock).

    python -m modules.lidar_logger.sim [--time-scale 1] [--port 0] [--xkf-valid-at 2] ...

With ``--follow-udp PORT`` the aircraft is the DSP simulator's (``python -m modules.dsp.sim --truth-udp
127.0.0.1:PORT``): the clock is the DSP's simulated time, the terrain is anchored at the DSP's home (or
``--origin``) and ``--time-scale``/``--speed``/``--height`` are not used (sim/follow.py).

Started by a lockstep launch (``CROMAT_SIM`` in its environment) while following, it is a member of the
robot's barrier (sim/lockstep.py): its clock stands on the step's time and it answers once it has simulated it and
written what that time produced; without ``--follow-udp`` it takes no part.

Prints one JSON line ``{"mtig_port": "/dev/pts/N", "ldmrs_host": "127.0.0.1", "ldmrs_port": P, ...}`` then
serves until SIGINT or SIGTERM, and prints what it did as a second JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
from pathlib import Path

from bbcs import SessionConfig, forward_stop_signals, open_session
from bbcs.lockstep import settings_from_env
from modules.lidar_logger.clock import ScaledClock
from modules.lidar_logger.sim.follow import FollowClock, FollowedFlight, TruthReceiver
from modules.lidar_logger.sim.ldmrs_sim import LdmrsOptions, LdmrsSimulator
from modules.lidar_logger.sim.lockstep import DEFAULT_MEMBER, SAMPLE_PERIOD_S, SimMember, StepClock, server_state
from modules.lidar_logger.sim.mtig_sim import MTiGSimulator
from modules.lidar_logger.sim.world import SEED_UTC_START, Flight, World


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m modules.lidar_logger.sim",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--time-scale", type=float, default=1.0, help="simulated seconds per wall second")
    p.add_argument("--port", type=int, default=0, help="LD-MRS TCP port on 127.0.0.1 (0 = any free port)")
    p.add_argument("--utc-start", type=float, default=SEED_UTC_START,
                   help="UTC (POSIX s) at simulation start")
    p.add_argument("--gps-fix-at", type=float, default=1.0, help="status 0 -> 5 at this simulated time (s)")
    p.add_argument("--xkf-valid-at", type=float, default=2.0, help="status 5 -> 7 at this simulated time (s)")
    p.add_argument("--speed", type=float, default=20.0, help="m/s")
    p.add_argument("--height", type=float, default=90.0, help="flight height above the terrain origin (m)")
    p.add_argument("--return-fraction", type=float, default=1.0, help="share of beams that return an echo")
    p.add_argument("--silent-after", type=float, help="stop sending scans this many s after StartMeasure")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--follow-udp", type=int, metavar="PORT",
                   help="fly with the DSP simulator's aircraft: its truth datagrams on 127.0.0.1:PORT (0 = any)")
    p.add_argument("--origin", type=float, nargs=3, metavar=("LAT", "LON", "ALT"),
                   help="terrain origin (default: the DSP's home when following, else 37.4261 -6.0032 50)")
    p.add_argument("--pty-link", help="also make this path a symlink to the MTi-G pty (a stable name)")
    p.add_argument("--lockstep-member", default=DEFAULT_MEMBER,
                   help="its member name in a lockstep simulation (CROMAT_SIM; with --follow-udp)")
    args = p.parse_args(argv)

    try:
        settings = settings_from_env() if args.follow_udp is not None else None
    except ValueError as exc:
        print(f"lidar-sim: {exc}", file=sys.stderr)
        return 2
    origin = tuple(args.origin) if args.origin else None
    receiver: TruthReceiver | None = None
    clock = StepClock() if settings is not None else FollowClock()
    if args.follow_udp is not None:
        world = World(clock=clock, utc_start=args.utc_start, gps_fix_at=args.gps_fix_at,
                      xkf_valid_at=args.xkf_valid_at, **({"origin_lla": origin} if origin else {}))
        world.flight = FollowedFlight(origin, on_anchor=world.set_origin)
        receiver = TruthReceiver(world.clock, world.flight, port=args.follow_udp).start()  # type: ignore[arg-type]
    else:
        world = World(clock=ScaledClock(args.time_scale), utc_start=args.utc_start,
                      flight=Flight(speed=args.speed, height=args.height),
                      gps_fix_at=args.gps_fix_at, xkf_valid_at=args.xkf_valid_at,
                      **({"origin_lla": origin} if origin else {}))
    lockstep = settings is not None
    options = LdmrsOptions(return_fraction=args.return_fraction, silent_after=args.silent_after,
                           seed=args.seed, release_grid=SAMPLE_PERIOD_S if lockstep else None)
    done = threading.Event()
    forward_stop_signals(lambda _signum: done.set())  # never a lock in a signal handler
    session = member = None
    try:
        with MTiGSimulator(world, **({"sample_period": SAMPLE_PERIOD_S} if lockstep else {})) as imu:
            link = Path(args.pty_link) if args.pty_link else None
            if link is not None:  # before the LD-MRS listens: a launcher waiting on its port finds the link there
                link.unlink(missing_ok=True)
                link.symlink_to(imu.port)
            with LdmrsSimulator(world, options, port=args.port) as lidar:
                if settings is not None:  # a member before the readiness line: waited for from the first steps
                    assert isinstance(clock, StepClock)
                    session = open_session(SessionConfig(mode="client", connect=settings.connect))
                    member = SimMember(session, settings.robot, args.lockstep_member, clock,
                                       server_state(imu, lidar))
                ready = {"mtig_port": imu.port, "ldmrs_host": lidar.host, "ldmrs_port": lidar.port,
                         "time_scale": args.time_scale}
                if receiver is not None:
                    ready.update(follow_udp=receiver.port, time_scale="the DSP's")
                if member is not None:
                    ready.update(lockstep_member=args.lockstep_member)
                print(json.dumps(ready), flush=True)
                while not done.wait(0.2):
                    pass
                if link is not None:
                    link.unlink(missing_ok=True)
                print(json.dumps({"scans_sent": len(lidar.device.sent_scans),
                                  "ldmrs_commands": len(lidar.device.commands),
                                  "mtig_messages": len(imu.device.received),
                                  "poses_sent": len(imu.device.poses_sent),
                                  **({} if receiver is None else {"truth_received": receiver.received,
                                                                  "truth_lost": receiver.lost,
                                                                  "truth_invalid": receiver.invalid}),
                                  **({} if member is None else {"lockstep_answers": member.answers})}),
                      flush=True)
    finally:
        if member is not None:
            member.close()
        if session is not None:
            session.close()
        if receiver is not None:
            receiver.stop()
    return 0




if __name__ == "__main__":
    sys.exit(main())
