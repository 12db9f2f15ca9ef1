"""The ground station's side of fleet allocation: post a fleet task, watch what every RAL decided.

``cromat gcs fleet post --target ID,LAT,LON,ALT[,KIND[,DEADLINE_S]] ...`` puts a :class:`FleetTask` on
``cromat/@fleet/task/<id>`` through any router of the mesh (signed with the station's ``--cert``/``--key`` when it
has them: a secured robot adopts only signed tasks, docs/fleet.md), then waits until every robot that answered shows the
same decision (equal digests) and prints who flies what. ``cromat gcs fleet status [TASK]`` prints the fleet
states as they are now. The station allocates nothing: it only reads what the robots decided.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from collections.abc import Iterable
from typing import Any, TextIO

import msgspec
import zenoh
import zenoh.ext

from bbcs import keys
from bbcs.contracts.fleet import MAX_TARGETS, FleetDecision, FleetState, FleetTarget, FleetTask
from bbcs.signing import SigningError, StationSigner
from ral.gcs.waypoints import load_polygon
from ral.survey_area import parse_area

log = logging.getLogger(__name__)


class FleetView:
    """Every RAL's latest :class:`FleetState` (history: what they published before the view existed too)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self.lock = threading.Condition()
        self.states: dict[str, FleetState] = {}
        self._sub = zenoh.ext.declare_advanced_subscriber(
            session, keys.fleet_state_key("*"), self._on_state,
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            recovery=zenoh.ext.RecoveryConfig(periodic_queries=None, heartbeat=True))

    def _on_state(self, sample: zenoh.Sample) -> None:
        try:
            st = msgspec.msgpack.decode(sample.payload.to_bytes(), type=FleetState)
        except msgspec.MsgspecError:
            return
        with self.lock:
            self.states[st.robot] = st
            self.lock.notify_all()

    def close(self) -> None:
        self._sub.undeclare()

    def post(self, task: FleetTask, signer: StationSigner | None = None,
             lifetime_s: float | None = None, reach_s: float = 3.0, live: Iterable[str] = ()) -> FleetTask:
        """Put ``task``, signed by ``signer`` (a station with a TLS identity: secured robots adopt only signed
        tasks, bbcs/signing.py) and adoptable for ``lifetime_s`` (default: ``bbcs.signing.default_lifetime_s``);
        returns what was put. A signed task names the robots it is for: ``live`` (the RALs alive now, from their
        liveliness tokens) and every robot whose fleet state this view holds; a view opened just now may not hold
        every robot's state yet, so a station passes ``live``. The put waits up to ``reach_s`` until this session
        knows a robot's task subscriber (the router tells it once it knows one): a put that reaches the router
        before any robot's subscription does is delivered to no one."""
        if signer is not None:
            if not task.robots:  # the robots it is for, inside the signature: a capture flies no other one
                with self.lock:
                    seen = sorted(set(self.states) | set(live))
                task = msgspec.structs.replace(task, robots=seen)
            task = signer.sign(task, lifetime_s=lifetime_s)
        publisher = self.session.declare_publisher(keys.fleet_task_key(task.id))
        matched = threading.Event()
        listener = publisher.declare_matching_listener(lambda status: status.matching and matched.set())
        try:
            if not (publisher.matching_status.matching or matched.wait(reach_s)):
                log.warning("fleet task %s put with no robot's task subscriber in sight after %g s", task.id, reach_s)
            self.session.put(keys.fleet_task_key(task.id), msgspec.msgpack.encode(task))  # to the router either way
        finally:
            listener.undeclare()
            publisher.undeclare()
        return task

    def decisions(self, task: str) -> dict[str, FleetDecision]:
        """Robot → its latest decision for ``task``."""
        with self.lock:
            return {r: d for r, st in self.states.items() for d in st.decisions if d.task == task}

    def answered(self, task: str) -> set[str]:
        """Robots that know ``task`` (bid, abstained, or finished it)."""
        with self.lock:
            return {r for r, st in self.states.items() if any(b.task == task for b in st.bids)}

    def agreed(self, task: str, robots: set[str] | None = None) -> FleetDecision | None:
        """The decision every answering robot (or every robot of ``robots``) holds, if they all hold the same."""
        decs = self.decisions(task)
        who = robots if robots is not None else self.answered(task)
        if not who or not who <= set(decs):
            return None
        digests = {decs[r].digest for r in who}
        rounds = {decs[r].round for r in who}
        return decs[min(who)] if len(digests) == 1 and len(rounds) == 1 else None

    def wait(self, pred: Any, timeout_s: float) -> Any:
        end = time.monotonic() + timeout_s
        with self.lock:
            while True:
                got = pred()
                if got:
                    return got
                left = end - time.monotonic()
                if left <= 0:
                    return got
                self.lock.wait(min(left, 0.2))

    def abstentions(self, task: str) -> dict[str, str]:
        """Robot → why it does not bid on ``task`` in its latest word (robots that bid are not listed)."""
        with self.lock:
            return {r: b.abstained for r, st in self.states.items() for b in st.bids
                    if b.task == task and b.state is None and b.abstained}

    def visited(self, task: str) -> set[str]:
        prefix = f"{task}/"
        with self.lock:
            return {d.removeprefix(prefix) for st in self.states.values() for d in st.done if d.startswith(prefix)}


def parse_target(text: str, index: int, now: float) -> FleetTarget:
    """``ID,LAT,LON,ALT[,KIND[,DEADLINE_S]]``; the deadline is seconds from now."""
    parts = [p.strip() for p in text.split(",")]
    if not 4 <= len(parts) <= 6:
        raise ValueError(f"--target {index + 1} {text!r}: expected ID,LAT,LON,ALT[,KIND[,DEADLINE_S]]")
    try:
        fields: dict[str, Any] = {"id": parts[0], "lat": float(parts[1]), "lon": float(parts[2]),
                                  "alt": float(parts[3])}
        if len(parts) > 4 and parts[4]:
            fields["kind"] = parts[4]
        if len(parts) > 5:
            fields["deadline"] = now + float(parts[5])
        return msgspec.convert(fields, FleetTarget)
    except (ValueError, msgspec.ValidationError) as exc:
        raise ValueError(f"--target {index + 1} {text!r}: {exc}") from exc


def _polygon_corners(path: str) -> list[tuple[float, float]]:
    return [(v.lat, v.lon) for v in load_polygon(path)]


def parse_area_arg(text: str, index: int) -> list[FleetTarget]:
    """``--area``: ``ID;ALT;SPACING_M;`` then the corners ``LAT,LON;LAT,LON;...`` or one GeoJSON Polygon file
    (``.geojson``/``.json``, the same files ``cromat gcs survey`` and ``world add-nfz`` read)."""
    return parse_area(text, index, polygon_file=_polygon_corners)


def add_parser(sub: Any) -> None:
    """``cromat gcs fleet ...`` (registered by ral/gcs/cli.py)."""
    f = sub.add_parser("fleet", help="fleet tasks allocated by the robots among themselves")
    fs = f.add_subparsers(dest="fleet_command", required=True)
    p = fs.add_parser("post", help="post a fleet task and print the allocation the robots agree on")
    p.add_argument("--id", required=True, help="task id (one key chunk)")
    p.add_argument("--target", action="append", default=[], metavar="ID,LAT,LON,ALT[,KIND[,DEADLINE_S]]")
    p.add_argument("--area", action="append", default=[],
                   metavar="ID;ALT;SPACING_M;LAT,LON;LAT,LON;LAT,LON[;...] or ID;ALT;SPACING_M;POLYGON.geojson",
                   help="an area to survey, split among the robots: the centres of a SPACING_M grid inside the "
                        "polygon (its corners, or a GeoJSON Polygon file) become targets ID.0, ID.1, … at ALT "
                        "(metres above sea level)")
    p.add_argument("--one-per-robot", action="store_true", help="at most one target per robot")
    p.add_argument("--balance", action="store_true",
                   help="share the targets so that the last robot finishes soonest (always on with --area)")
    p.add_argument("--speed", type=float, help="flight speed of the robots' paths, m/s")
    p.add_argument("--wait", type=float, default=15.0, help="seconds to wait for the robots to agree (15)")
    p.add_argument("--valid-for", type=float, metavar="S", help="with --cert: seconds a robot may adopt the signed "
                   "task (default: an hour, or the last deadline plus ten minutes; docs/fleet.md)")
    s = fs.add_parser("status", help="what every robot decided and visited")
    s.add_argument("task", nargs="?", help="one task (default: every task)")


def format_decision(dec: FleetDecision, visited: set[str]) -> list[str]:
    lines = [f"task {dec.task} round {dec.round} digest {dec.digest} cost {dec.cost:.1f} "
             f"bidders {','.join(dec.bidders) or '-'}"]
    for robot, route in dec.routes.items():
        shown = [f"{x}{'*' if x in visited else ''}" for x in route]
        lines.append(f"  {robot:<12} {' '.join(shown) or '-'}")
    if dec.unassigned:
        lines.append(f"  unassigned   {' '.join(dec.unassigned)}")
    return lines


def run(session: zenoh.Session, args: argparse.Namespace, out: TextIO, live: Iterable[str] = ()) -> int:
    """Exit codes as ``cromat gcs``: 0 agreed, 2 bad target, 3 no agreement within ``--wait``; 4 agreed, but some
    targets are left unassigned (no robot that answered bids on them: each one's reason is printed).

    ``live``: the robots whose RAL is alive now. The station waits for the word of each (a bid or an abstention)
    before it prints an agreement: the first robot to decide may have decided alone, and the robots decide
    again once the others' word arrives (ral/fleet_protocol.py)."""
    view = FleetView(session)
    try:
        if args.fleet_command == "post":
            now = time.time()
            try:
                targets = [parse_target(x, i, now) for i, x in enumerate(args.target)]
                for i, x in enumerate(args.area):
                    targets += parse_area_arg(x, i)
                if not targets:
                    raise ValueError("nothing to do: give --target or --area")
                if args.speed is not None and not args.speed > 0:
                    raise ValueError(f"--speed must be positive, not {args.speed:g} (none: each robot's cruise speed)")
                if args.valid_for is not None and not args.valid_for > 0:
                    raise ValueError(f"--valid-for must be positive, not {args.valid_for:g}")
                if len(targets) > MAX_TARGETS:
                    raise ValueError(f"{len(targets)} targets in all: a fleet task holds at most {MAX_TARGETS}")
                task = msgspec.convert({"id": args.id, "targets": [msgspec.to_builtins(x) for x in targets],
                                        "one_per_robot": args.one_per_robot, "speed": args.speed,
                                        "balance": args.balance or bool(args.area),
                                        "posted_by": "cromat gcs"}, FleetTask)
            except (ValueError, msgspec.ValidationError) as exc:
                print(f"cromat gcs fleet: {exc}", file=out)
                return 2
            try:  # a station with a TLS identity signs with it: a secured robot adopts nothing else
                signer = StationSigner.from_files(args.cert, args.key) if getattr(args, "cert", None) else None
            except SigningError as exc:
                print(f"cromat gcs fleet: {exc}", file=out)
                return 2
            task = view.post(task, signer, args.valid_for, live=live)
            expected = set(task.robots) | set(live)
            dec = view.wait(lambda: view.agreed(task.id) if expected <= view.answered(task.id) else None, args.wait)
            silent = sorted(expected - view.answered(task.id))
            if dec is None and silent:  # the word of some never came: what the others agreed on, said as such
                dec = view.agreed(task.id)
            if dec is None:
                decs = view.decisions(task.id)
                print(f"no agreement within {args.wait:g} s: answered {sorted(view.answered(task.id))}, "
                      f"digests { {r: d.digest for r, d in decs.items()} }", file=out)
                return 3
            print("\n".join(format_decision(dec, view.visited(task.id))), file=out)
            for robot, why in sorted(view.abstentions(task.id).items()):
                print(f"  {robot} does not bid: {why}", file=out)
            if silent:
                print(f"  no word within {args.wait:g} s from {', '.join(silent)} (alive, but not answering: "
                      "a task signed by someone it does not trust, or a link down)", file=out)
            print(f"agreed by {len(view.answered(task.id))} robots", file=out)
            if dec.unassigned:
                print(f"{len(dec.unassigned)} of {len(task.targets)} targets unassigned: no robot that answered can "
                      "do them (or reach them before their deadline)", file=out)
                return 4
            return 0
        view.wait(lambda: bool(view.states), 2.0)
        tasks = sorted({d.task for st in view.states.values() for d in st.decisions})
        for tid in [args.task] if args.task else tasks:
            decs = view.decisions(tid)
            for robot, dec in sorted(decs.items()):
                print(f"{robot}: round {dec.round} digest {dec.digest}", file=out)
            agreed = view.agreed(tid)
            if agreed is not None:
                print("\n".join(format_decision(agreed, view.visited(tid))), file=out)
        return 0
    finally:
        view.close()
