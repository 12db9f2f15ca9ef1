"""The RAL's bus side of fleet allocation: feeds :class:`~ral.fleet_protocol.FleetNode` from Zenoh and flies its
share through the RAL's ordinary task path.

- ``cromat/@fleet/task/*``: tasks put by ground stations; ``cromat/*/@ral/fleet``: every RAL's
  :class:`FleetState` (a safe state: history for late joiners, recovery of lost samples), republished every
  period so a robot cut off and healed catches up; liveliness of ``cromat/*/@alive/ral``: who is in the fleet
  (a RAL whose token goes away, by a kill or a lost link, drops out and its targets are allocated again).
- The callbacks only hand samples to the node under a lock; the RAL's main-loop tick runs the protocol and
  queues what to fly as a job of the RAL's worker, which sends it through :meth:`Ral.handle` like a ground
  station's ``goto`` (admitted against the robot's own limits and geofence, then to the Module Manager).
- On a secured robot (``[bus.tls]``) every fleet task, from a ground station's put or inside a peer's fleet
  state, passes :class:`TaskGate` first: only a task signed by one of the manifest's ground stations with a
  certificate of the fleet CA (``bbcs/signing.py``), not revoked, within its validity and not replayed, reaches
  the protocol; anything else is dropped, counted and logged once, so it is never adopted, bid on or relayed in
  this robot's own fleet state.
- Losing the mesh changes nothing in the robot: its task, its failsafe and its link to its own modules go through
  its own router; only its view of the others goes stale.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh
import zenoh.ext

from bbcs import Direction, Kind, Publisher, Safety, SlotSpec, keys
from bbcs.contracts import gri
from bbcs.contracts import tasks as t
from bbcs.contracts.fleet import FleetState, FleetTask
from bbcs.geodesy import distance_m
from bbcs.signing import FleetTrust, task_check
from ral.fleet_protocol import Execute, FleetConfig, FleetNode, OwnState
from ral.signed import ReplayMemory, SignatureGate

log = logging.getLogger("ral.fleet")
DEFAULT_SPEED = 5.0
BUSY_DEFAULT_S = 30.0
"""Time left on a movement task the fleet did not start, when the RAL cannot tell (it ends when it ends)."""


def can_do_from(param: str, kinds: list[str]) -> frozenset[str]:
    """What target kinds this robot bids on: the RAL parameter ``fleet_can_do`` (comma-separated; ``none``: it
    never bids), else ``visit`` if it can fly a ``goto``."""
    if param.strip():
        return frozenset() if param.strip() == "none" else frozenset(k.strip() for k in param.split(",") if k.strip())
    return frozenset({"visit"}) if "goto" in kinds else frozenset()


class TaskGate(SignatureGate):
    """Which fleet tasks this robot may adopt (:class:`~ral.signed.SignatureGate`): signed, not revoked, within
    its validity, and not an older signature of a task id it holds a newer one of
    (:class:`~ral.signed.ReplayMemory`)."""

    def __init__(self, trust: FleetTrust | None, clock: Callable[[], float], remember: int = 1024,
                 robot: str | None = None) -> None:
        # ``robot``: refuse a task signed for other robots (bbcs.signing.task_check, issue 32 item 8)
        super().__init__(trust, clock, "fleet task", remember, logger=log,
                         replay=ReplayMemory(lambda task: task.id),  # type: ignore[attr-defined]
                         **({"check": task_check(robot)} if robot is not None else {}))

    def admit(self, task: FleetTask, source: str, label: str = "") -> bool:  # type: ignore[override]
        return super().admit(task, source, label or task.id)


class FleetLink:
    """One RAL's fleet membership. ``own`` gives the robot's state at each tick; ``fly`` queues an Execute on the
    RAL's worker."""

    def __init__(self, robot: str, kind: str, own: Callable[[], OwnState], fly: Callable[[Execute], None],
                 cfg: FleetConfig | None = None, clock: Callable[[], float] | None = None,
                 trust: FleetTrust | None = None) -> None:
        self.node = FleetNode(robot, kind, cfg)
        self.robot = robot
        self.own = own
        self.fly = fly
        self.clock = clock or time.time
        self.gate = TaskGate(trust, self.clock, robot=robot)
        self.lock = threading.Lock()
        self.entities: list[Any] = []
        self.pub: Publisher[FleetState] | None = None

    def start(self, session: zenoh.Session) -> None:
        self.pub = Publisher(session, keys.fleet_state_key(self.robot),
                             SlotSpec("fleet", FleetState, Direction.OUT, Kind.STATE, Safety.SAFE))
        self.entities = [
            session.declare_subscriber(keys.fleet_task_key("*"), self._on_task),
            zenoh.ext.declare_advanced_subscriber(
                session, keys.fleet_state_key("*"), self._on_state,
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
                recovery=zenoh.ext.RecoveryConfig(periodic_queries=None, heartbeat=True),
                subscriber_detection=True),
            session.liveliness().declare_subscriber(keys.alive_pattern("*", "ral"), self._on_alive, history=True),
        ]

    def stop(self) -> None:
        for entity in reversed(self.entities):
            entity.undeclare()
        self.entities.clear()
        if self.pub is not None:
            self.pub.close()

    def _on_task(self, sample: zenoh.Sample) -> None:
        try:
            task = msgspec.msgpack.decode(sample.payload.to_bytes(), type=FleetTask)
        except msgspec.MsgspecError as exc:
            log.warning("unreadable fleet task dropped: %s", exc)
            return
        with self.lock:
            if self._admit(task, "a ground station's put"):
                self._repost(task)
                self.node.post(task, self.clock())

    def _admit(self, task: FleetTask, source: str) -> bool:
        """Under ``lock``: a task this node already adopted, unchanged, passes without a second verification."""
        run = self.node.runs.get(task.id)
        return (run is not None and run.task == task) or self.gate.admit(task, source)

    def _repost(self, task: FleetTask) -> None:
        """Under ``lock``, ``task`` admitted: a station's newer signature of a task id this robot holds replaces the
        held copy if it asks for the same work (the run goes on, and the fresher signature is what this robot
        relays); different work under a known id is not flown (the protocol knows a task by its id: a station
        posts new work under a new id)."""
        run = self.node.runs.get(task.id)
        if run is None or run.task == task or not task.signed_at > run.task.signed_at:
            return
        if _work(run.task) == _work(task):
            run.task = task
        else:
            log.warning("fleet task %s re-signed with other targets or options: not applied (a task id is flown "
                        "once; post new work under a new id)", task.id)

    def _on_state(self, sample: zenoh.Sample) -> None:
        try:
            state = msgspec.msgpack.decode(sample.payload.to_bytes(), type=FleetState)
        except msgspec.MsgspecError as exc:
            log.warning("unreadable fleet state dropped: %s", exc)
            return
        with self.lock:
            tasks = [x for x in state.tasks if self._admit(x, f"{state.robot}'s fleet state")]
            for task in tasks:
                self._repost(task)
            if len(tasks) != len(state.tasks):
                state = msgspec.structs.replace(state, tasks=tasks)
            self.node.on_state(state, self.clock())

    def _on_alive(self, sample: zenoh.Sample) -> None:
        try:
            robot, _ = keys.parse_alive_key(str(sample.key_expr))
        except ValueError:
            return
        with self.lock:
            if sample.kind == zenoh.SampleKind.DELETE:
                self.node.on_lost(robot, self.clock())
            else:
                self.node.on_alive(robot)

    def tick(self) -> None:
        """Run the protocol once: bid, decide, mark visited targets, publish, queue what to fly."""
        own = self.own()
        with self.lock:
            now = self.clock()
            todo = self.node.tick(own, now)
            state = self.node.state(now) if self.node.publish_due(now) else None
        if state is not None and self.pub is not None:
            self.pub.publish(state)
        for job in todo:
            self.fly(job)


def _work(task: FleetTask) -> FleetTask:
    """``task`` without its signature and validity: what a robot flies."""
    return msgspec.structs.replace(task, signed_at=0.0, valid_until=0.0, signer_cert=b"", signature=b"")


def goto_of(job: Execute) -> gri.TaskRequest:
    """The ordinary task that flies a share: a goto through its targets in order."""
    return t.Goto(waypoints=[t.Waypoint(lat=x.lat, lon=x.lon, alt=x.alt) for x in job.targets], speed=job.task.speed)


def state_of_charge(battery_v: float | None, empty_v: float, full_v: float) -> float | None:
    """The state of charge (0..1) a bid weighs, from the pack voltage: linear between the empty and full voltages
    and clamped. Coarse (a LiPo's curve is flat in its middle and sags under load), but it orders robots the
    right way, which is all an auction needs; None when the robot reports no voltage."""
    if battery_v is None:
        return None
    return min(1.0, max(0.0, (battery_v - empty_v) / (full_v - empty_v)))


def busy_seconds(task: t.TaskInfo, pos: Any, speed: float) -> float:
    """How long a movement task the fleet did not give keeps the robot, as its bids count it: for a path (goto,
    follow_path) the rest of it from where the robot is (from the waypoint nearest it, or the next one once it is
    past it) at the task's speed or the robot's; for any other movement (a take-off, a survey, an orbit, ...)
    ``BUSY_DEFAULT_S``, a coarse stand-in stated in docs/fleet.md."""
    params = task.params
    if not isinstance(params, (t.Goto, t.FollowPath)) or pos is None:
        return BUSY_DEFAULT_S
    wps = params.waypoints
    pace = params.speed or speed
    near = min(range(len(wps)), key=lambda k: distance_m(pos.lat, pos.lon, wps[k].lat, wps[k].lon))
    if near + 1 < len(wps):
        ahead, leg = wps[near + 1], distance_m(wps[near].lat, wps[near].lon, wps[near + 1].lat, wps[near + 1].lon)
        if distance_m(pos.lat, pos.lon, ahead.lat, ahead.lon) < leg:  # past the nearest one, on the next leg
            near += 1
    metres = distance_m(pos.lat, pos.lon, wps[near].lat, wps[near].lon) + sum(
        distance_m(a.lat, a.lon, b.lat, b.lon) for a, b in zip(wps[near:], wps[near + 1:], strict=False))
    return metres / pace


def own_state_of(telemetry: Any, speed: float, can_do: frozenset[str], live_tasks: list[t.TaskInfo],
                 available: bool = True, pack_v: tuple[float, float] | None = None) -> OwnState:
    """The robot's bid state from the RAL's view: its position, its speed, its battery (``pack_v``: the empty and
    full voltages; None: not weighed), how long movement tasks the fleet did not give it keep it busy (the longest
    of them, ``busy_seconds``), and whether
    its own failsafe is in force (``available`` False)."""
    pos = telemetry.position if telemetry is not None else None
    volts = getattr(telemetry, "battery_v", None) if telemetry is not None else None
    battery = state_of_charge(volts, *pack_v) if pack_v is not None else None
    busy = max((busy_seconds(i, pos, speed) for i in live_tasks
                if i.task_type == "movement" and i.origin != "fleet" and i.kind not in ("hold", "")), default=0.0)
    flying = any(i.origin == "fleet" and i.status == "running" for i in live_tasks)
    return OwnState(lat=pos.lat if pos else None, lon=pos.lon if pos else None, alt=pos.alt if pos else None,
                    speed=speed, can_do=can_do, battery=battery, busy_s=busy, flying_share=flying,
                    available=available)
