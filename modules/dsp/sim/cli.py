"""``cromat dsp-sim`` / ``python -m modules.dsp.sim``: a simulated DSP on a pty or a TCP port.

The first line on stdout is what the PC should open, as a pyserial URL: the pty slave path (``--pty``) or
``socket://127.0.0.1:PORT`` (``--tcp``). The simulator then runs until SIGTERM/SIGINT or ``--duration``.

Started by a lockstep launch (``CROMAT_SIM`` in its environment, docs/simulation.md) it is the robot's stepper:
it joins the robot's bus and advances one frame at a time, each once every module has handled the last.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading

from bbcs import SessionConfig, open_session
from bbcs.contracts import dsp as p
from bbcs.geodesy import valid_lat_lon
from bbcs.lockstep import Follower, SimSettings, Stepper, settings_from_env
from modules.dsp.codec import DSP_TO_PC_LENGTHS
from modules.dsp.sim.control import ControlPort
from modules.dsp.sim.faults import BadTelemetry, FaultInjector
from modules.dsp.sim.machine import DspParams
from modules.dsp.sim.server import DspSimulator
from modules.dsp.sim.transport import PtyEndpoint, TcpEndpoint
from modules.dsp.sim.truth import TruthSender
from modules.dsp.sim.vehicle import VehicleParams


def _host_port(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host or "127.0.0.1", int(port)


def _home(text: str) -> tuple[float, float, float]:
    try:
        lat, lon, alt = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LAT,LON,ALT, got {text!r}") from None
    if not valid_lat_lon(lat, lon):
        raise argparse.ArgumentTypeError(f"home {text!r} is not a valid position")
    return lat, lon, alt


def _failure(text: str) -> tuple[float, int]:
    code, sep, at = text.partition("@")
    try:
        value = p.ErrorCode[code.upper()] if not code.isdigit() else int(code)
        return float(at), int(value)
    except (KeyError, ValueError):
        raise argparse.ArgumentTypeError(f"expected CODE@SECONDS (e.g. GPS_LOST@30), got {text!r}") from None


def _rate(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"a rate is a probability in [0, 1], got {text}")
    return value


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="cromat dsp-sim", description=__doc__.splitlines()[0])
    where = ap.add_mutually_exclusive_group()
    where.add_argument("--pty", action="store_true", help="serve on a new pty pair (default)")
    where.add_argument("--tcp", type=_host_port, metavar="HOST:PORT",
                       help="serve on TCP (port 0: any free port)")
    ap.add_argument("--baud", type=int, default=921_600, help="the DSP's UART speed (default 921600)")
    ap.add_argument("--rate", type=float, default=50.0, help="physics steps per simulated second (50)")
    ap.add_argument("--time-scale", type=float, default=1.0, help="simulated seconds per wall second (1)")
    ap.add_argument("--record", metavar="FILE", help="append every received command as a JSON line")
    ap.add_argument("--home", type=_home, default=(37.4117, -6.0025, 12.0), metavar="LAT,LON,ALT",
                    help="take-off point; ALT = ground level, m MSL")
    ap.add_argument("--max-speed", type=float, default=10.0, help="airframe horizontal speed limit, m/s")
    ap.add_argument("--takeoff-height", type=float, default=10.0, help="take-off climbs to this height, m")
    ap.add_argument("--battery", type=float, default=25.2, help="battery voltage at start, V (drains while the "
                    "rotor turns)")
    ap.add_argument("--corrupt", type=_rate, default=0.0, help="probability a byte is corrupted")
    ap.add_argument("--drop", type=_rate, default=0.0, help="probability a byte is lost")
    ap.add_argument("--garbage", type=_rate, default=0.0, help="probability a frame is preceded by garbage")
    ap.add_argument("--fault-dir", choices=("tx", "rx", "both"), default="both",
                    help="apply faults to what the DSP sends, receives, or both")
    ap.add_argument("--fail", type=_failure, action="append", default=[], metavar="CODE@SECONDS",
                    help="raise DSP error CODE at simulated time SECONDS (repeatable)")
    ap.add_argument("--bad-telemetry", type=int, default=0, metavar="N",
                    help="every Nth telemetry frame carries an out-of-range value with a good CRC (0: never)")
    ap.add_argument("--seed", type=int, help="random seed for faults")
    ap.add_argument("--control", type=_host_port, metavar="HOST:PORT",
                    help="fault injection at run time: a UDP port on loopback taking 'spoil FIELD=VALUE [COUNT]' "
                         "(modules/dsp/sim/control.py), e.g. one frame with position.lat=200")
    ap.add_argument("--truth-udp", type=_host_port, metavar="HOST:PORT",
                    help="send the aircraft's true state every physics step to this loopback UDP port, for the "
                         "lidar simulators (modules.lidar_logger.sim --follow-udp)")
    ap.add_argument("--duration", type=float, default=0.0,
                    help="exit after this many wall seconds (0: never)")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="dsp-sim: %(levelname)s %(message)s")
    logging.getLogger("modules.dsp.sim.server").setLevel(logging.INFO)  # the lockstep summary at the end
    if args.time_scale <= 0 or args.rate <= 0 or args.max_speed <= 0:
        print("dsp-sim: --time-scale, --rate and --max-speed must be positive", file=sys.stderr)
        return 2
    spoiling = args.bad_telemetry > 0 or args.control is not None
    bad_telemetry = BadTelemetry(every=max(0, args.bad_telemetry)) if spoiling else None
    try:  # bound first: a busy or non-loopback control port stops the simulator before it offers a line
        control = ControlPort(*args.control, bad_telemetry) if args.control and bad_telemetry else None
    except (OSError, ValueError) as exc:
        print(f"dsp-sim: --control: {exc}", file=sys.stderr)
        return 2
    if control is not None:
        print(f"dsp-sim: control port udp://{control.host}:{control.port}", file=sys.stderr)
    try:
        endpoint = TcpEndpoint(*args.tcp) if args.tcp else PtyEndpoint(args.baud)
    except OSError as exc:
        print(f"dsp-sim: cannot open the line: {exc}", file=sys.stderr)
        return 1
    faults = {}
    if args.corrupt or args.drop or args.garbage:
        for direction, ids in (("tx", DSP_TO_PC_LENGTHS), ("rx", {})):
            if args.fault_dir in (direction, "both"):
                false_ids = {i: max(lens) for i, lens in ids.items()}
                seed = None if args.seed is None else args.seed + (direction == "rx")
                faults[direction] = FaultInjector(corrupt=args.corrupt, drop=args.drop, garbage=args.garbage,
                                                  seed=seed, false_ids=false_ids)
    home_lat, home_lon, home_alt = args.home
    try:
        truth = TruthSender(*args.truth_udp, args.time_scale) if args.truth_udp else None
    except ValueError as exc:
        print(f"dsp-sim: --truth-udp: {exc}", file=sys.stderr)
        endpoint.close()
        return 2
    try:
        settings = settings_from_env()
    except ValueError as exc:
        print(f"dsp-sim: {exc}", file=sys.stderr)
        endpoint.close()
        return 2
    if settings is not None and args.tcp is None:
        print("dsp-sim: lockstep needs --tcp (a pty has no connection to count the line's bytes on)",
              file=sys.stderr)
        endpoint.close()
        return 2
    sim = DspSimulator(
        endpoint, params=DspParams(home_lat=home_lat, home_lon=home_lon, home_alt=home_alt,
                                   takeoff_height=args.takeoff_height),
        vehicle_params=VehicleParams(max_speed=args.max_speed, battery_full=args.battery),
        rate_hz=args.rate, time_scale=args.time_scale,
        baud=args.baud, tx_faults=faults.get("tx"), rx_faults=faults.get("rx"), record_path=args.record,
        fail_at=args.fail, seed=args.seed,
        bad_telemetry=bad_telemetry, truth=truth,
        frame_s=settings.step_s if settings else 0.1,
        speed=lockstep_speed(settings, args.time_scale) if settings else args.time_scale)

    def on_signal(signum: int, frame: object) -> None:
        sim.stop()

    # handlers first, then the readiness line: whoever reads it may signal us at once and expects a clean stop
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    url = endpoint.path if isinstance(endpoint, PtyEndpoint) else f"socket://{endpoint.host}:{endpoint.port}"
    print(url, flush=True)
    session = None
    stepper: Stepper | Follower | None = None
    if settings is not None:  # after the readiness line: the DSP module may connect while the bus session opens
        session = open_session(SessionConfig(mode="client", connect=settings.connect))
        if settings.leads:
            stepper = Stepper(session, settings.robot, deadline_s=settings.deadline_s, fleet=settings.fleet)
            sim.use_stepper(stepper)
        else:  # a fleet's other robot: the first robot's simulator steps, this one follows
            stepper = Follower(session, settings.robot)
            sim.use_follower(stepper)
    timer = threading.Timer(args.duration, sim.stop) if args.duration > 0 else None
    if timer is not None:
        timer.daemon = True
        timer.start()
    try:
        sim.run()
    finally:
        if control is not None:
            control.close()
        if timer is not None:
            timer.cancel()
        if stepper is not None:
            stepper.close()
        if session is not None:
            session.close()
    return 0


def lockstep_speed(settings: SimSettings, time_scale: float) -> float | None:
    """The lockstep pace: the launch's speed, or this simulator's ``--time-scale`` (None: as fast as possible)."""
    if settings.speed == "max":
        return None
    return time_scale if settings.speed is None else settings.speed


if __name__ == "__main__":
    sys.exit(main())
