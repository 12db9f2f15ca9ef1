"""``cromat gcs world ...`` and ``cromat gcs sync ...``: the shared world model and fleet time from a ground
station (docs/world.md, docs/sync.md). Functions for scripts, then the command line that wraps them.

A synchronised start: the station measures its own clock's offset to the reference robot (the first named, in
name order) with the same four-timestamp probe the RALs use, picks ``start_at = reference clock now + lead``,
and sends every robot the same :class:`~bbcs.contracts.sync.SyncStart`; each converts it to its own clock.
"""

from __future__ import annotations

import argparse
import re
import threading
import time
from pathlib import Path
from typing import TextIO

import msgspec

from bbcs.contracts import sync as s
from bbcs.contracts import tasks as t
from bbcs.contracts import world as w
from bbcs.contracts.signed import seal_of
from bbcs.signing import SigningError, StationSigner, signer_name
from ral import sync
from ral.gcs.api import Gcs, GcsError, NoReply, UsageError
from ral.gcs.waypoints import WaypointFileError, load_polygon
from ral.sync_bus import probe
from ral.world_bus import fetch_snapshots

COMMANDS = ("world", "sync")
_world_reply = msgspec.msgpack.Decoder(w.WorldReply)
_sync_reply = msgspec.msgpack.Decoder(s.SyncReply)
_report = msgspec.msgpack.Decoder(s.ClockReport)
_encoder = msgspec.msgpack.Encoder()


# ---------------------------------------------------------------- API


def _ask(gcs: Gcs, key: str, request: msgspec.Struct, decoder: msgspec.msgpack.Decoder, robot: str,
         timeout_s: float | None = None) -> msgspec.Struct:
    for reply in gcs.session.get(key, payload=_encoder.encode(request), timeout=timeout_s or gcs.timeout_s):
        if reply.ok is None:
            continue
        try:
            return decoder.decode(reply.ok.payload.to_bytes())
        except msgspec.MsgspecError as exc:
            raise GcsError(f"unreadable reply from robot {robot!r}: {exc}") from None
    raise NoReply(f"robot {robot!r} did not answer on {key} (not running, or this station may not ask it)")


def signed_request(request: w.WorldPut | w.WorldDelete, signer: StationSigner | None) -> w.WorldPut | w.WorldDelete:
    """``request`` as the wire carries it, with ``signer``'s signature of the edit (:func:`w.edit_of_request`): a
    secured robot applies no zone nor removal without it. Unchanged without a signer (an unsecured fleet)."""
    if signer is None:
        return request
    wire = msgspec.msgpack.decode(msgspec.msgpack.encode(request), type=type(request))  # ranges, floats as floats
    edit = w.edit_of_request(wire)
    if edit is None:  # a robot's own kind of entry: nothing to sign
        return wire
    signed = signer.sign(edit)
    return msgspec.structs.replace(wire, **seal_of(signed))


def world_request(gcs: Gcs, robot: str, request: w.WorldRequest,
                  signer: StationSigner | None = None) -> w.WorldReply:
    """Add / remove an entry through ``robot``'s RAL (it publishes it to every RAL), or start a tracking. An edit
    is signed by ``signer`` (the station's TLS identity) when given."""
    if signer is not None and isinstance(request, w.WorldPut | w.WorldDelete):
        request = signed_request(request, signer)
    reply = _ask(gcs, w.world_request_key(robot), request, _world_reply, robot)
    assert isinstance(reply, w.WorldReply)
    return reply


def world_snapshot(gcs: Gcs, robot: str) -> w.WorldSnapshot:
    snaps = fetch_snapshots(gcs.session, robot, gcs.timeout_s)
    if not snaps:
        raise NoReply(f"robot {robot!r} did not answer its world model query")
    return snaps[0]


def sync_request(gcs: Gcs, robot: str, request: s.SyncRequest) -> s.SyncReply:
    reply = _ask(gcs, s.sync_key(robot), request, _sync_reply, robot)
    assert isinstance(reply, s.SyncReply)
    return reply


def clock_report(gcs: Gcs, robot: str, timeout_s: float | None = None) -> s.ClockReport:
    """The next per-peer clock offsets ``robot`` publishes."""
    got: list[s.ClockReport] = []
    ready = threading.Event()

    def keep(sample: object) -> None:
        try:
            got.append(_report.decode(sample.payload.to_bytes()))  # type: ignore[attr-defined]
        except msgspec.MsgspecError:
            return
        ready.set()

    sub = gcs.session.declare_subscriber(s.clock_offsets_key(robot), keep)
    try:
        ready.wait(timeout_s or gcs.timeout_s)
    finally:
        sub.undeclare()
    if not got:
        raise NoReply(f"no clock offsets from robot {robot!r}")
    return got[-1]


def offset_to(gcs: Gcs, robot: str, probes: int = 8) -> sync.Estimate:
    """This station's clock offset to ``robot``'s sync clock (minimum-delay of ``probes`` exchanges)."""
    est = sync.OffsetEstimator(window=probes)
    for _ in range(probes):
        sample = probe(gcs.session, robot, time.time)
        if sample is not None:
            est.add(robot, sample)
    found = est.estimate(robot, time.time())
    if found is None:
        raise NoReply(f"robot {robot!r} did not answer its clock probes")
    return found


def sync_group(start_at: float) -> str:
    """The group name :func:`sync_start` gives a start at ``start_at`` (unless told another)."""
    return f"sync-{start_at:.6f}"


def sync_start(gcs: Gcs, robots: list[str], task: t.TaskParams, lead_s: float = 3.0,
               group: str = "") -> tuple[str, float, dict[str, s.SyncReply]]:
    """Ask every robot of ``robots`` to start ``task`` at one instant ``lead_s`` from now; returns the
    reference robot, the instant on its clock, and each robot's reply. All or none: a robot that does not answer
    its clock probe stops it before anything is sent (NoReply); one that refuses cancels it on the others."""
    reference = sorted(robots)[0]
    offsets = {r: offset_to(gcs, r) for r in sorted(robots)}  # every robot answers, or nothing is sent
    start_at = time.time() + offsets[reference].offset_s + lead_s
    request = s.SyncStart(group=group or sync_group(start_at), reference=reference, start_at=start_at, task=task)
    replies: dict[str, s.SyncReply] = {}
    for robot in robots:
        try:
            replies[robot] = sync_request(gcs, robot, request)
        except NoReply as exc:
            replies[robot] = s.SyncReply(accepted=False, reason=str(exc))
    if not all(r.accepted for r in replies.values()):  # one refused: the others do not start either
        for robot, reply in list(replies.items()):
            if reply.accepted:
                undo = sync_request(gcs, robot, s.SyncCancel(group=request.group))
                replies[robot] = s.SyncReply(accepted=False, local_start=reply.local_start,
                                             reason="cancelled: another robot refused" if undo.accepted
                                             else f"could not be cancelled: {undo.reason}")
    return reference, start_at, replies


# ---------------------------------------------------------------- command line


def add_parsers(sub: argparse._SubParsersAction) -> None:
    wp = sub.add_parser("world", help="the fleet's shared world model (no-fly zones, geofences, targets, surveyed)")
    wsub = wp.add_subparsers(dest="world_command", required=True)
    k = wsub.add_parser("show", help="every entry of a robot's world model")
    k.add_argument("robot")
    for name, what in (("add-nfz", "a no-fly zone"), ("add-geofence", "a keep-in geofence")):
        k = wsub.add_parser(name, help=f"add {what} from a GeoJSON Polygon (through ROBOT, to every robot)")
        k.add_argument("robot")
        k.add_argument("polygon", metavar="POLYGON.geojson")
        k.add_argument("--id", help="entry id (default: the file name)")
        k.add_argument("--label", default="", help="a human name shown in refusals")
    k = wsub.add_parser("remove", help="remove an entry (from every robot)")
    k.add_argument("robot")
    k.add_argument("id")
    k = wsub.add_parser("track", help="ROBOT points its pan & tilt at a target of the model, whoever saw it")
    k.add_argument("robot")
    k.add_argument("target", help="target entry id, e.g. target.uav_a")
    sp = sub.add_parser("sync", help="fleet time: clock offsets, synchronised start, formation")
    ssub = sp.add_subparsers(dest="sync_command", required=True)
    k = ssub.add_parser("clocks", help="a robot's measured clock offset to every peer")
    k.add_argument("robot")
    k = ssub.add_parser("start", help="robots start one task at the same instant")
    k.add_argument("robots", nargs="+")
    k.add_argument("--task", choices=["take_off", "land", "hold"], default="take_off")
    k.add_argument("--lead", type=float, default=3.0, help="seconds from now (default 3)")
    k = ssub.add_parser("formation", help="FOLLOWER keeps a separation from LEADER")
    k.add_argument("follower")
    k.add_argument("leader")
    k.add_argument("--north", type=float, default=0.0, help="metres")
    k.add_argument("--east", type=float, default=0.0, help="metres")
    k.add_argument("--up", type=float, default=0.0, help="metres")
    k.add_argument("--speed", type=float, help="m/s")
    k = ssub.add_parser("stop-formation", help="FOLLOWER stops following")
    k.add_argument("follower")


def format_entry(e: w.WorldEntry) -> str:
    head = f"{e.id:<28} v{e.version:<3} {e.origin:<10} by {e.author or e.origin:<10}"
    b = e.body
    if e.deleted or b is None:
        return f"{head} removed"
    if isinstance(b, w.Target):
        return f"{head} target   {b.lat:.6f} {b.lon:.6f} {b.alt:.1f} m, seen by {b.seen_by} at {b.seen_at:.3f}"
    kind = {"no_fly_zone": "no-fly", "geofence": "geofence", "surveyed": "surveyed"}[str(type(b).__struct_config__.tag)]
    name = f" ({b.name})" if getattr(b, "name", "") else ""
    signed = f", signed by {signer_name(e.signer_cert) or '?'}" if e.signer_cert else ""
    return f"{head} {kind:<8} {len(b.polygon)} vertices{name}{signed}"


def _entry_id(args: argparse.Namespace) -> str:
    if args.id:
        return args.id
    return re.sub(r"[^A-Za-z0-9_.\-]", "_", Path(args.polygon).stem)[:64] or "zone"


def _print(reply: w.WorldReply | s.SyncReply, out: TextIO, done: str) -> int:
    if reply.accepted:
        print(done, file=out)
        return 0
    print(f"rejected: {reply.reason}", file=out)
    return 1


def run(gcs: Gcs, args: argparse.Namespace, out: TextIO) -> int:
    if args.command == "world":
        c = args.world_command
        try:  # a station with a TLS identity signs its edits with it: a secured robot applies nothing else
            signer = StationSigner.from_files(args.cert, args.key) if getattr(args, "cert", None) else None
        except SigningError as exc:
            raise UsageError(str(exc)) from None
        if c == "show":
            snap = world_snapshot(gcs, args.robot)
            print(f"world of {snap.robot}: {len(snap.entries)} entries, digest {snap.digest}", file=out)
            for entry in snap.entries:
                print(format_entry(entry), file=out)
            return 0
        if c in ("add-nfz", "add-geofence"):
            polygon = load_polygon(args.polygon)
            body: w.Body = (w.NoFlyZone(polygon=polygon, name=args.label) if c == "add-nfz"
                            else w.Geofence(polygon=polygon, name=args.label))
            try:
                request = w.WorldPut(id=_entry_id(args), body=body, author=gcs.name)
                request = msgspec.convert(msgspec.to_builtins(request), w.WorldPut)
            except msgspec.ValidationError as exc:
                raise WaypointFileError(f"bad world entry: {exc}") from None
            reply = world_request(gcs, args.robot, request, signer)
            return _print(reply, out, f"added {request.id} (version {reply.entry.version if reply.entry else '?'})")
        if c == "remove":
            return _print(world_request(gcs, args.robot, w.WorldDelete(id=args.id, author=gcs.name), signer), out,
                          f"removed {args.id}")
        reply = world_request(gcs, args.robot, w.TrackTarget(target=args.target))
        return _print(reply, out, f"tracking {args.target} (look_at task {reply.task_id})")
    c = args.sync_command
    if c == "clocks":
        report = clock_report(gcs, args.robot)
        print(f"{'peer':<16} {'offset ms':>10} {'delay ms':>9} {'samples':>7}", file=out)
        for p in report.peers:
            print(f"{p.peer:<16} {p.offset_s * 1000:>10.3f} {p.delay_s * 1000:>9.3f} {p.samples:>7}", file=out)
        return 0
    if c == "start":
        task = msgspec.convert({"type": args.task}, t.TaskParams)
        reference, start_at, replies = sync_start(gcs, args.robots, task, args.lead)
        print(f"start {args.task} at {start_at:.6f} on {reference}'s clock", file=out)
        code = 0
        for robot, reply in replies.items():
            state = f"at {reply.local_start:.6f} on its own clock" if reply.accepted else f"REFUSED: {reply.reason}"
            print(f"  {robot:<16} {state}", file=out)
            code = code or (0 if reply.accepted else 1)
        return code
    if c == "formation":
        request = s.FormationKeep(leader=args.leader, north_m=args.north, east_m=args.east, up_m=args.up,
                                  speed=args.speed)
        return _print(sync_request(gcs, args.follower, request), out, f"{args.follower} follows {args.leader}")
    return _print(sync_request(gcs, args.follower, s.StopFormation()), out, f"{args.follower} stopped following")
