"""The ``cromat`` command: one dispatcher, each subcommand's ``main(argv) -> int`` in the package that owns it."""

from __future__ import annotations

import importlib
import sys

COMMANDS: dict[str, tuple[str, str]] = {
    "launch": ("module_manager.cli", "start a robot from a manifest (router, manager, modules), supervise it"),
    "router": ("bbcs.router", "run a robot's Zenoh router"),
    "conf": ("cromat.conf", "check a robot .conf: every error with file:line (conf check FILE)"),
    "fleet": ("module_manager.fleet", "launch N simulated robots from a fleet manifest, their routers meshed"),
    "gcs": ("ral.gcs.cli", "ground control station: robots, watch, task, abort, modules, route, errors"),
    "certs": ("cromat.certs", "create a CA and certificates for a robot router, a GCS and modules"),
    "dsp-sim": ("modules.dsp.sim.cli", "run the DSP simulator on a pty or a TCP port"),
    "lidar": ("modules.lidar_logger.cli", "run the lidar logger, read and georeference its logs"),
    "bus": ("cromat.tools.bus_cli", "introspect a bus: list, echo, hz, schema, pub, graph (like ros2 topic)"),
    "record": ("cromat.tools.record", "record a robot's bus to MCAP (opens in Foxglove and the mcap CLI)"),
    "replay": ("cromat.tools.replay", "republish an MCAP recording onto a router (1x, Nx, as fast as possible)"),
    "foxglove": ("cromat.tools.foxglove_bridge", "bridge a robot's bus to a Foxglove WebSocket server"),
    "bag": ("cromat.tools.bag", "look into MCAP recordings: info, filter, cat, export to CSV (like ros2 bag)"),
    "param": ("cromat.tools.param_cli", "a running module's parameters: list, get, set (like ros2 param)"),
    "mavlink": ("cromat.mavlink.cli", "a MAVLink gateway: every robot a vehicle for QGroundControl, MAVSDK, pymavlink"),
}


def usage() -> str:
    width = max(map(len, COMMANDS))
    rows = "\n".join(f"  {name.ljust(width)}  {text}" for name, (_, text) in COMMANDS.items())
    return f"usage: cromat COMMAND [ARGS...]\n\ncommands:\n{rows}\n\n'cromat COMMAND --help' for its options."


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args or args[0] in {"-h", "--help", "help"}:
        print(usage())
        return 0 if args else 2
    name, rest = args[0], args[1:]
    if name not in COMMANDS:
        print(f"cromat: unknown command {name!r}\n\n{usage()}", file=sys.stderr)
        return 2
    module_name = COMMANDS[name][0]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name and module_name.startswith(exc.name):
            print(f"cromat {name}: not available in this build ({module_name} is missing)", file=sys.stderr)
            return 2
        raise
    return int(module.main(rest) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
