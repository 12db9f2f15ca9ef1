"""``cromat mavlink``: make every robot behind a router a MAVLink vehicle (docs/mavlink.md).

``--connect``/``--ca``/``--cert``/``--key``/``--config`` are ``cromat gcs``'s (same environment variables); the
gateway is a ground station named ``--name`` (default ``mavlink``; on a secured robot its certificate's CN must be
one of the manifest's ``[bus.tls] gcs`` identities). Exit codes: 0 stopped by a signal, 2 usage, manifest or
endpoint error, 3 router unreachable.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading

from bbcs.conf.errors import ConfError
from bbcs.signing import SigningError, StationSigner
from cromat.mavlink.dialect import read_key
from cromat.mavlink.endpoints import QGC_PORT, EndpointError, SerialPort, TcpServer, UdpTarget, parse_host_port
from cromat.mavlink.gateway import GCS_TIMEOUT_S, Gateway
from cromat.mavlink.vehicle import RobotSpec, describe, spec_from_manifest
from ral.gcs.api import Gcs, Unreachable, UsageError, session_config

log = logging.getLogger("cromat.mavlink")


def build_parser() -> argparse.ArgumentParser:
    env = os.environ
    p = argparse.ArgumentParser(prog="cromat mavlink", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--connect", action="append",
                   default=[e for e in env.get("CROMAT_GCS_CONNECT", "").split(",") if e.strip()] or None,
                   help="robot router endpoint (repeatable; env CROMAT_GCS_CONNECT), default tcp/127.0.0.1:7447")
    p.add_argument("--ca", default=env.get("CROMAT_GCS_CA"), help="CA certificate (PEM) for tls/ endpoints")
    p.add_argument("--cert", default=env.get("CROMAT_GCS_CERT"), help="this gateway's certificate (mutual TLS)")
    p.add_argument("--key", default=env.get("CROMAT_GCS_KEY"), help="this gateway's private key (PEM)")
    p.add_argument("--config", metavar="FILE", default=env.get("CROMAT_GCS_CONFIG"), help="Zenoh JSON5 config file")
    p.add_argument("--name", default="mavlink", help="ground-station name (liveliness token), default mavlink")
    p.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the router and task replies")
    p.add_argument("--manifest", action="append", default=[], metavar="FILE",
                   help="a robot's launch manifest: its name, .conf values (parameters) and limits (repeatable)")
    p.add_argument("--robot", action="append", default=[], metavar="NAME[=SYSID]",
                   help="serve this robot, with this MAVLink system id (repeatable; also sets a manifest's id)")
    p.add_argument("--all", action="store_true",
                   help="also serve every other robot that appears (the default when no robot is named)")
    p.add_argument("--udp", action="append", default=[], metavar="HOST:PORT",
                   help=f"send to a ground station over UDP (repeatable); default 127.0.0.1:{QGC_PORT} when no "
                        "endpoint is given")
    p.add_argument("--tcp", action="append", default=[], type=int, metavar="PORT", help="serve MAVLink over TCP")
    p.add_argument("--serial", action="append", default=[], metavar="URL",
                   help="a telemetry radio: DEVICE[:BAUD] (default 57600) or a pyserial URL")
    p.add_argument("--bind", default="127.0.0.1",
                   help="address the UDP and TCP sockets bind (default loopback: nothing is reachable from "
                        "elsewhere unless told)")
    p.add_argument("--signing-key", metavar="FILE",
                   help="MAVLink 2 signing key (32 bytes, 64 hex digits, or a passphrase); unsigned, forged and "
                        "replayed frames are then dropped, and every frame sent is signed")
    p.add_argument("--gcs-timeout", type=float, default=GCS_TIMEOUT_S, metavar="S",
                   help="the robots' GRI link is held while a MAVLink ground station's HEARTBEAT came within S "
                        f"seconds (default {GCS_TIMEOUT_S:g}); then released: the robots' failsafe counts from there")
    p.add_argument("-v", "--verbose", action="store_true", help="log every robot and refusal")
    return p


def robot_specs(args: argparse.Namespace) -> list[RobotSpec]:
    """Robots named on the command line; errors name the manifest file and line."""
    ids: dict[str, int | None] = {}
    for text in args.robot:
        name, sep, sysid = text.partition("=")
        if sep and (not sysid.isdigit() or not 1 <= int(sysid) <= 255):
            raise UsageError(f"--robot {text!r}: the system id must be 1..255")
        ids[name] = int(sysid) if sep else None
    specs: dict[str, RobotSpec] = {}
    for path in args.manifest:
        spec = spec_from_manifest(path)
        specs[spec.name] = spec
    for name, sysid in ids.items():
        spec = specs.setdefault(name, RobotSpec(name=name))
        spec.sysid = sysid
    return list(specs.values())


def open_endpoints(args: argparse.Namespace) -> list:
    endpoints: list = []
    try:
        udp = args.udp or ([] if args.tcp or args.serial else [f"127.0.0.1:{QGC_PORT}"])
        for text in udp:
            host, port = parse_host_port(text, "--udp")
            endpoints.append(UdpTarget(host, port, args.bind))
        for port in args.tcp:
            endpoints.append(TcpServer(port, args.bind))
        for url in args.serial:
            endpoints.append(SerialPort(url))
    except EndpointError:
        for ep in endpoints:
            ep.close()
        raise
    return endpoints


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, stream=sys.stderr,
                        format="cromat mavlink: %(message)s")
    try:
        specs = robot_specs(args)
        key = read_key(args.signing_key) if args.signing_key else None
        signer = StationSigner.from_files(args.cert, args.key) if args.cert and args.key else None
        cfg = session_config(args.connect, ca=args.ca, cert=args.cert, key=args.key, config_file=args.config,
                             connect_timeout_s=args.timeout)
    except (UsageError, ConfError, ValueError, OSError, SigningError) as exc:
        print(f"cromat mavlink: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - a manifest error (module_manager's ManifestError) names file:line
        print(f"cromat mavlink: {exc}", file=sys.stderr)
        return 2
    if not args.gcs_timeout > 0:
        print(f"cromat mavlink: --gcs-timeout {args.gcs_timeout:g}: give a positive number of seconds", file=sys.stderr)
        return 2
    try:
        endpoints = open_endpoints(args)
    except EndpointError as exc:
        print(f"cromat mavlink: {exc}", file=sys.stderr)
        return 2
    try:
        gcs = Gcs(cfg, name=args.name, timeout_s=args.timeout)
    except Unreachable as exc:
        for ep in endpoints:
            ep.close()
        print(f"cromat mavlink: {exc}", file=sys.stderr)
        return 3
    gateway = Gateway(gcs, endpoints, specs, discover=args.all or not specs, signing_key=key,
                      announce=lambda line: print(f"cromat mavlink: {line}", flush=True), signer=signer,
                      gcs_timeout_s=args.gcs_timeout)
    stop = threading.Event()

    def on_signal(*_: object) -> None:
        gateway.stop()
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    for spec in specs:
        print(f"cromat mavlink: robot {describe(spec)}", flush=True)
    names = ", ".join(ep.name for ep in endpoints)
    signed = ", signed" if key else ""
    print(f"cromat mavlink: serving on {names}{signed} (Ctrl+C stops)", flush=True)
    try:
        gateway.run()
    finally:
        gcs.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
