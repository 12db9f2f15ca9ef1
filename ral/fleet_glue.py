"""The RAL's side of the fleet: fleet allocation (ral/fleet.py) fed with this robot's state and flying its
share as ordinary tasks, and world/synchronisation requests (ral/world_bus.py, ral/sync_bus.py) run on the RAL's
worker. A mixin of :class:`ral.module.Ral`: its state lives there."""

from __future__ import annotations

import threading
from typing import Any

import zenoh
import zenoh.ext

from bbcs.contracts import gri
from bbcs.contracts import tasks as t
from bbcs.contracts.pan_tilt import DatosPT
from bbcs.signing import FleetTrust
from ral.fleet import FleetLink, can_do_from, goto_of, own_state_of
from ral.fleet_protocol import Execute, FleetConfig, OwnState
from ral.tasks import (
    Rejected,
    admit,
    available_kinds,
)


class FleetGlue:
    """The RAL's side of the fleet (a mixin of the RAL module)."""

    def _fleet_start(self, session: zenoh.Session) -> None:
        cfg = FleetConfig(bid_window_s=self.cfg.fleet_bid_window_s,
                          reach_m=max(self.cfg.position_tolerance_m, 10.0),
                          reach_alt_m=max(self.cfg.altitude_tolerance_m, 5.0))
        self._fleet = FleetLink(self.robot, self.cfg.kind, self._fleet_own,
                                lambda job: self._jobs.put(lambda: self._fleet_fly(job)), cfg, clock=self.clock,
                                trust=self._fleet_trust())
        self._fleet.start(session)

    def _fleet_trust(self) -> FleetTrust | None:
        """Who may sign the fleet tasks this RAL adopts: None (any task) unless the robot is secured, i.e. the
        launch passed ``fleet_ca`` or the RAL's own bus is TLS."""
        tls = self.context.bus.tls
        ca = self.cfg.fleet_ca or (tls.root_ca if tls is not None else "")
        if not ca:
            return None
        signers = [x.strip() for x in self.cfg.fleet_signers.split(",") if x.strip()]
        trust = FleetTrust.from_files(ca, signers, self.cfg.fleet_crl or None)
        if signers:
            self.log.info("fleet tasks and world zone edits adopted only if signed by %s (certificate of %s)",
                          ", ".join(signers), ca)
        else:
            self.log.warning("secured bus but no fleet_signers: every fleet task and world zone edit is refused")
        return trust

    def _fleet_own(self) -> OwnState:
        with self.lock:
            kinds = available_kinds(self.available, self.task_names)
            speed = self.limits.cruise_speed or min(5.0, self.limits.max_speed)
            pack = (self.cfg.battery_empty_v, self.cfg.battery_full_v) if self.cfg.battery_full_v else None
            return own_state_of(self.telemetry, speed, can_do_from(self.cfg.fleet_can_do, kinds),
                                list(self._live.values()), available=not self.link.in_force, pack_v=pack)

    def _fleet_fly(self, job: Execute) -> None:
        goto = goto_of(job)
        with self.lock:
            grounded = self.telemetry is not None and self.telemetry.airborne is False
            self._then.clear()  # a new job replaces whatever an earlier one was waiting to fly
        first: t.TaskParams = goto
        if grounded:  # a path is flown from the air (ral/tasks.py: PATH_TASKS): the take-off, then the targets
            first = t.TakeOff(height=self.limits.takeoff_height_m or t.TakeOff().height)
        reply = self.handle(first, origin="fleet")
        if grounded and reply.accepted:
            with self.lock:
                self._then[reply.task_id] = goto
        self.log.info("fleet task %s round %d: %s %s%s", job.task.id, job.round, [x.id for x in job.targets],
                      "accepted" if reply.accepted else f"refused: {reply.reason}",
                      " (taking off first)" if grounded and reply.accepted else "")

    def _world_sync_start(self) -> None:
        from ral.sync import SkewedClock
        from ral.sync_bus import SyncNode
        from ral.world_bus import WorldNode

        assert self.session is not None
        self.sync_clock = SkewedClock(self.cfg.sync_clock_offset_s, self.cfg.sync_clock_drift_ppm)
        self.world_node = WorldNode(self.session, self.robot, self.sync_clock, start_task=self.world_sync_handle,
                               point_at=self._point_at_target,
                               trust=self._fleet.gate.trust if self._fleet is not None else None)
        self.sync_node = SyncNode(self.session, self.robot, self.sync_clock, start_task=self.world_sync_handle,
                                   check_task=self._world_sync_check)

    def _world_sync_stop(self) -> None:
        for node in (getattr(self, "sync_node", None), getattr(self, "world_node", None)):
            if node is not None:
                node.close()

    def world_sync_handle(self, task: t.TaskParams, timeout_s: float = 30.0) -> gri.TaskReply:
        """A task from the fleet side (synchronised start, formation, target tracking), run on the worker thread
        in turn with the ground stations' tasks."""
        job = WorldSyncJob(lambda: self.handle(task))
        self._jobs.put(job)
        if not job.done.wait(timeout_s) or job.result is None:
            return gri.TaskReply(accepted=False, reason=f"the RAL did not run the {t.kind_of(task)} in {timeout_s:g} s")
        return job.result

    def _world_refusal(self, request: gri.TaskRequest) -> str | None:
        """What the shared world model forbids (no-fly zones, geofences), or None."""
        world = getattr(self, "world_node", None)
        if world is None:
            return None
        with self.lock:
            position = self.telemetry.position if self.telemetry else None
        return world.refusal(request, position)

    def _world_sync_check(self, task: t.TaskParams) -> str | None:
        """Why ``task`` would be refused now (world model, then admission), or None."""
        why = self._world_refusal(task)
        if why is not None:
            return why
        with self.lock:
            plan = admit(task, available=self.available, task_names=self.task_names, limits=self.limits,
                         cfg=self.judge_cfg, telemetry=self.telemetry, home=self.home)
        return plan.reason if isinstance(plan, Rejected) else None

    def _point_at_target(self, target: Any, task_id: int) -> bool:
        """A tracked world target moved: aim the running look_at task at it (False once that task ended)."""
        with self.lock:
            running = task_id in self._live
        if running:
            self._put_pt_datos(task_id, DatosPT(latitud=target.lat, longitud=target.lon, altura=target.alt))
        return running



class WorldSyncJob:
    """A fleet-side task for the RAL's worker thread; ``done`` is set when ``result`` is there."""

    def __init__(self, run: Any) -> None:
        self._run = run
        self.result: gri.TaskReply | None = None
        self.done = threading.Event()

    def run(self) -> None:
        try:
            self.result = self._run()
        finally:
            self.done.set()
