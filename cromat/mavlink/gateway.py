"""The gateway process: robots' GRI on one side, MAVLink endpoints on the other, one loop thread in between.

Threads: each endpoint reads on its own; Zenoh calls back with GRI states and events; one worker per vehicle sends
its task requests to the RAL (a request may take seconds: the RAL answers once the task runs). All of them only put
items on :attr:`Gateway.inbox`; the loop thread alone decodes, decides, encodes and sends, so no vehicle state is
shared between threads.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from bbcs.contracts import gri
from cromat.mavlink import commands as cm
from cromat.mavlink import fence, mission, statustext, telemetry
from cromat.mavlink import plan as pl
from cromat.mavlink.dialect import Encoder, Message, Parser, Signing, mav
from cromat.mavlink.endpoints import Endpoint
from cromat.mavlink.vehicle import RobotSpec, Vehicle
from ral.gcs.api import Gcs, GcsError

log = logging.getLogger("cromat.mavlink")

LOOP_S = 0.02
PARAMS_PER_TICK = 40
"""PARAM_VALUEs sent per loop turn on a list request (a radio link is not flooded with a whole .conf at once)."""
REPLACE_JOB = -1
"""Not a MAVLink command: the follow_path of a mission uploaded while the last one flew."""
FENCE_JOB = -2
"""Not a MAVLink command: a fence upload's world-model edits."""
RTL_LAND_JOB = -3
"""Not a MAVLink command: the landing that ends a return to launch once the robot is home."""
MISSION_STEP_JOB = -4
"""Not a MAVLink command: a mission's next task (its path after its take-off; its landing or return after its path);
the job's key is what the STATUSTEXT calls it."""
GCS_TIMEOUT_S = 3.0
"""A MAVLink ground station is heard while its HEARTBEATs (1 Hz) come within this (three missed: gone)."""
CAPABILITIES = (mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mav.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT | mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | mav.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE)


class _Worker:
    """Sends one vehicle's GRI requests in order, on a thread of its own."""

    def __init__(self, name: str, run: Callable[[Any], None]) -> None:
        self.jobs: queue.Queue[Any] = queue.Queue()
        self.run = run
        self.thread = threading.Thread(target=self._loop, name=f"mavlink.{name}", daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        while True:
            job = self.jobs.get()
            if job is None:
                return
            self.run(job)

    def stop(self) -> None:
        self.jobs.put(None)
        self.thread.join(5.0)


class Gateway:
    def __init__(self, gcs: Gcs, endpoints: Sequence[Endpoint], specs: Sequence[RobotSpec] = (), *,
                 discover: bool = True, signing_key: bytes | None = None, clock: Callable[[], float] = time.monotonic,
                 retry_s: float = 1.5, announce: Callable[[str], None] = lambda line: None,
                 signer: Any = None, gcs_timeout_s: float = GCS_TIMEOUT_S) -> None:
        """``specs``: robots named by the operator (manifest or flag); ``discover``: also every other robot whose GRI
        state appears (a fleet), each with the next free system id. ``gcs_timeout_s``: the GRI link of every robot
        served is held only while a MAVLink ground station's HEARTBEAT came within this (the operator is there)."""
        self.gcs = gcs
        self.endpoints = list(endpoints)
        self.specs = {s.name: s for s in specs}
        self.discover = discover
        self.clock = clock
        self.retry_s = retry_s
        self.announce = announce
        self.signer = signer
        self.gcs_timeout_s = gcs_timeout_s
        self.gcs_heard: float | None = None
        """When a MAVLink ground station's HEARTBEAT last came (the gateway's clock); None: never."""
        """A ``bbcs.signing.StationSigner`` (the station's TLS identity): signs fence edits, which a secured fleet's
        world model adopts only signed."""
        self.inbox: queue.Queue[tuple[str, Any]] = queue.Queue()
        self.refusals = 0
        self._last_refusal_log: dict[str, float] = {}
        self.in_signing = Signing(signing_key, refused=self._refused) if signing_key else None
        self.out_signing = Signing(signing_key) if signing_key else None
        self.parsers: dict[str, Parser] = {}
        self.vehicles: dict[str, Vehicle] = {}
        self.by_sysid: dict[int, Vehicle] = {}
        self.workers: dict[str, _Worker] = {}
        self._chunk_id = 0
        self._stop = threading.Event()
        self._out_lock = threading.Lock()
        taken = [s.sysid for s in specs if s.sysid is not None]
        if len(set(taken)) != len(taken):
            raise ValueError("two robots were given the same MAVLink system id")

    # ---------------------------------------------------------------- start and stop

    def start(self) -> None:
        for ep in self.endpoints:
            ep.start(lambda peer, data: self.inbox.put(("bytes", (peer, data))))
        self.gcs.watch("*", lambda state: self.inbox.put(("state", state)))

    def stop(self) -> None:
        self._stop.set()

    def close(self) -> None:
        for w in self.workers.values():
            w.stop()
        for ep in self.endpoints:
            ep.close()

    def run(self) -> None:
        """The loop: until :meth:`stop`."""
        self.start()
        try:
            while not self._stop.is_set():
                self.turn()
        finally:
            self.close()

    def turn(self, wait_s: float = LOOP_S) -> None:
        """One turn of the loop: what came in, then what is due."""
        try:
            item = self.inbox.get(timeout=wait_s)
        except queue.Empty:
            item = None
        while item is not None:
            self._handle(*item)
            try:
                item = self.inbox.get_nowait()
            except queue.Empty:
                item = None
        self._periodic(self.clock())

    def _handle(self, what: str, data: Any) -> None:
        if what == "bytes":
            self._on_bytes(*data)
        elif what == "state":
            self._on_state(data)
        elif what == "event":
            self._on_event(data)
        elif what == "reply":
            self._on_reply(*data)

    # ---------------------------------------------------------------- robots

    def _next_sysid(self) -> int:
        reserved = {s.sysid for s in self.specs.values() if s.sysid is not None} | set(self.by_sysid)
        return next(i for i in range(1, 256) if i not in reserved)

    def _on_state(self, state: gri.GriState) -> None:
        v = self.vehicles.get(state.robot)
        if v is None:
            if state.robot not in self.specs and not self.discover:
                return
            v = self._add_vehicle(state.robot)
            if v is None:
                return
        first_state = v.state is None
        had_home = v.state is not None and v.state.home is not None
        v.state = state
        fresh = statustext.new_errors(v.seen_errors, state.errors)
        if not first_state:  # the errors listed when the gateway first sees a robot are history, not news
            for error in fresh:
                self._text(v, statustext.error_text(v.robot, error))
        if state.home is not None and not had_home:
            v.schedule.due_at.pop("HOME_POSITION", None)

    def _add_vehicle(self, robot: str) -> Vehicle | None:
        spec = self.specs.get(robot) or RobotSpec(name=robot)
        sysid = spec.sysid or self._next_sysid()
        if len(self.by_sysid) >= 254:
            log.warning("robot %s: no MAVLink system id left", robot)
            return None
        enc = Encoder(sysid, self._write, self.out_signing)
        v = Vehicle(spec, sysid, enc, retry_s=self.retry_s)
        v.boot = self.clock()
        self.vehicles[robot] = v
        self.by_sysid[sysid] = v
        self.workers[robot] = _Worker(robot, self._send_request)
        try:  # the link is held by _hold_links, while a MAVLink ground station is heard
            self.gcs.events(robot, lambda event: self.inbox.put(("event", event)))
        except GcsError as exc:
            log.warning("robot %s: %s", robot, exc)
        self.announce(f"robot {robot} is MAVLink system {sysid}")
        return v

    def _hold_links(self, now: float) -> None:
        """The GRI link of every robot served while a MAVLink ground station is heard, none otherwise: the gateway
        stands for its operator, so a QGroundControl gone quiet is a lost ground-station link to the robot (its
        heartbeat timeout, then its failsafe), as a ``cromat gcs link`` stopped would be."""
        heard = self.gcs_heard is not None and now - self.gcs_heard <= self.gcs_timeout_s
        for v in self.vehicles.values():
            if v.linked == heard:
                continue
            try:
                if heard:
                    self.gcs.hold_link(v.robot)
                else:
                    self.gcs.release_link(v.robot)
            except GcsError as exc:
                log.warning("robot %s: %s", v.robot, exc)
                continue
            v.linked = heard
            self.announce(f"link to {v.robot} held: a MAVLink ground station is heard" if heard else
                          f"link to {v.robot} released: no MAVLink ground station heard for "
                          f"{self.gcs_timeout_s:g} s")

    def _on_event(self, event: gri.GriEvent) -> None:
        v = self.vehicles.get(event.robot)
        if v is None:
            return
        v.on_event(event)
        self._text(v, statustext.event_text(event))
        if event.kind == "task_completed" and event.task_id and event.task_id == v.rtl_task and v.rtl_landing is None:
            self._rtl_home(v)
        self._mission_steps(v, event)

    def _mission_steps(self, v: Vehicle, event: gri.GriEvent) -> None:
        """A mission is a sequence of GRI tasks when it has a take-off or an end (plan.py): the next one starts when
        the last completes; one that fails, is replaced or cancelled ends the sequence (the robot does what the
        RAL does then)."""
        ended = event.kind in ("task_completed", "task_failed", "task_cancelled", "task_replaced", "aborted")
        if v.mission_takeoff is not None and event.task_id == v.mission_takeoff[0] and ended:
            offset = v.mission_takeoff[1]
            v.mission_takeoff = None
            if event.kind == "task_completed" and v.plan is not None and offset < len(v.plan.waypoints):
                self._step(v, cm.mission_path(v.context(), v.plan, offset), "take-off done, flying the mission")
            return
        run = v.run
        if (event.kind == "task_completed" and run is not None and event.task_id == run.task_id and v.plan is not None
                and v.plan.finish and not run.finished):
            run.finished = True
            if v.plan.finish == "land":
                if "land" in (v.state.available if v.state else {}):
                    self._step(v, cm.Send(gri.Land()), "mission complete, landing")
                else:
                    self._deny(v, f"mission complete; {v.robot} ({v.kind}) offers no land task: holding there")
                return
            outcome = cm.rtl(v.context())
            if isinstance(outcome, cm.Send):
                self._step(v, outcome, "mission complete, returning to launch")
            else:
                self._deny(v, f"mission complete, return refused: {outcome.reason}")  # type: ignore[union-attr]

    def _step(self, v: Vehicle, outcome: cm.Send, what: str) -> None:
        self.workers[v.robot].jobs.put((v.robot, MISSION_STEP_JOB, outcome, (0, 0), what))

    def _rtl_home(self, v: Vehicle) -> None:
        """A return to launch reached home: RETURN_ACTION ``land`` (the default, as PX4's RTL) lands there with a
        GRI ``land``; ``hover`` leaves the robot holding over home."""
        if v.spec.return_action == "hover":
            self._text(v, statustext.Text(mav.MAV_SEVERITY_INFO, f"{v.robot}: home reached, holding there "
                                          "(RETURN_ACTION hover)"))
            return
        if "land" not in (v.state.available if v.state else {}):
            self._deny(v, f"home reached; {v.robot} ({v.kind}) offers no land task: holding there")
            return
        v.rtl_landing = 0
        self.workers[v.robot].jobs.put((v.robot, RTL_LAND_JOB, cm.Send(gri.Land(), "rtl"), (0, 0), ()))

    # ---------------------------------------------------------------- output

    def _write(self, frame: bytes) -> None:
        for ep in self.endpoints:
            ep.send(frame)

    def _send(self, v: Vehicle, msg: Message | None) -> None:
        if msg is None:
            return
        with self._out_lock:
            v.encoder.send(msg)

    def _text(self, v: Vehicle, text: statustext.Text) -> None:
        self._chunk_id = self._chunk_id % 65535 + 1
        for part, chunk_id, seq in statustext.chunks(text.text, self._chunk_id):
            self._send(v, mav.MAVLink_statustext_message(text.severity, part, chunk_id, seq))

    def _deny(self, v: Vehicle, reason: str) -> None:
        self._text(v, statustext.Text(mav.MAV_SEVERITY_WARNING, f"{v.robot}: {reason}"))

    def _refused(self, why: str) -> None:
        self.refusals += 1
        now = time.monotonic()
        kind = why.split(" from")[0].split(" (")[0]  # at most one line a second per kind of refusal
        if now - self._last_refusal_log.get(kind, -math.inf) > 1.0:
            self._last_refusal_log[kind] = now
            log.warning("signing: refused %s (%d refused so far)", why, self.refusals)

    # ---------------------------------------------------------------- periodic

    def _periodic(self, now: float) -> None:
        self._hold_links(now)
        for v in list(self.vehicles.values()):
            if v.state is not None:
                for name in v.schedule.due(now):
                    for msg in self._telemetry(v, name, now):
                        self._send(v, msg)
                for seq in v.newly_reached():
                    self._send(v, mav.MAVLink_mission_item_reached_message(seq))
            for action in v.transfer.tick(now):
                self._mission_action(v, action)
            if v.param_queue:
                batch, v.param_queue = v.param_queue[:PARAMS_PER_TICK], v.param_queue[PARAMS_PER_TICK:]
                for i in batch:
                    self._send_param(v, i)

    def _telemetry(self, v: Vehicle, name: str, now: float) -> list[Message | None]:
        s = v.state
        assert s is not None
        boot_ms = int((now - v.boot) * 1000) & 0xFFFFFFFF
        has_gimbal = "pan_tilt" in s.available
        if name == "HEARTBEAT":
            return [telemetry.heartbeat(s, v.rtl_task)]
        if name == "SYS_STATUS":
            return [telemetry.sys_status(s, v.spec.battery_full_v, v.spec.battery_empty_v)]
        if name == "GLOBAL_POSITION_INT":
            return [telemetry.global_position_int(s, boot_ms)]
        if name == "ATTITUDE":
            return [telemetry.attitude(s, boot_ms)]
        if name == "VFR_HUD":
            return [telemetry.vfr_hud(s)]
        if name == "GPS_RAW_INT":
            return [telemetry.gps_raw_int(s, time.time())]
        if name == "HOME_POSITION":
            return [telemetry.home_position(s, time.time())]
        if name == "EXTENDED_SYS_STATE":
            return [telemetry.extended_sys_state(s)]
        if name == "MISSION_CURRENT":
            return [telemetry.mission_current(*v.mission_current())]
        if name == "GIMBAL_DEVICE_ATTITUDE_STATUS" and has_gimbal:
            return [telemetry.gimbal_attitude(s, boot_ms)]
        if name == "GIMBAL_MANAGER_STATUS" and has_gimbal:
            return [telemetry.gimbal_manager_status(boot_ms)]
        return []

    # ---------------------------------------------------------------- input

    def _on_bytes(self, peer: str, data: bytes) -> None:
        parser = self.parsers.get(peer)
        if parser is None:
            parser = self.parsers[peer] = Parser(self.in_signing)
        for msg in parser.feed(data):
            try:
                self._on_message(msg)
            except Exception:  # noqa: BLE001 - one bad message must not stop the gateway: logged with its content
                log.exception("handling %s", msg)

    def _targets(self, msg: Message) -> list[Vehicle]:
        target = getattr(msg, "target_system", 0)
        if target == 0:
            return list(self.vehicles.values())
        v = self.by_sysid.get(target)
        return [v] if v is not None else []

    def _on_message(self, msg: Message) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            if msg.type == mav.MAV_TYPE_GCS:  # a ground station is there (a vehicle's heartbeat is not one)
                self.gcs_heard = self.clock()
            return
        handler = _HANDLERS.get(kind)
        if handler is None:
            return
        partner = (msg.get_srcSystem(), msg.get_srcComponent())
        for v in self._targets(msg):
            handler(self, v, msg, partner)

    # ---------------------------------------------------------------- commands

    def _on_command(self, v: Vehicle, msg: Message, partner: mission.Partner) -> None:
        if msg.target_system == 0:
            return  # a command must name its vehicle (QGroundControl and MAVSDK always do)
        cmd = cm.command_of(msg)
        key = _command_key(cmd)
        if key in v.pending:  # the same command resent while its request is with the RAL
            self._ack(v, cmd.command, mav.MAV_RESULT_IN_PROGRESS, partner)
            return
        s = v.state
        outcome = cm.map_command(v.context(), cmd, (s.pan_deg, s.tilt_deg) if s else (None, None))
        log.info("%s: %s from %d/%d -> %s", v.robot, pl.command_name(cmd.command), *partner, outcome)
        if isinstance(outcome, cm.Deny):
            self._ack(v, cmd.command, outcome.result, partner)
            if outcome.result == mav.MAV_RESULT_DENIED:
                self._deny(v, outcome.reason)
        elif isinstance(outcome, cm.Local):
            self._local(v, cmd, outcome, partner)
        else:
            if v.state is None:
                self._ack(v, cmd.command, mav.MAV_RESULT_TEMPORARILY_REJECTED, partner)
                return
            if outcome.role == "pause":  # where the mission stands now: once the hold runs, its queue is gone
                v.pause_at()
            v.pending.add(key)
            self.workers[v.robot].jobs.put((v.robot, cmd.command, outcome, partner, key))

    def _send_request(self, job: tuple[str, int, cm.Send, mission.Partner, tuple | str]) -> None:
        """On the vehicle's worker: the RAL's verdict, handed back to the loop."""
        robot, command, outcome, partner, key = job
        try:
            reply: gri.TaskReply | str = self.gcs.send(robot, outcome.request)
        except GcsError as exc:
            reply = str(exc)
        self.inbox.put(("reply", (robot, command, outcome, partner, reply, key)))

    def _on_reply(self, robot: str, command: int, outcome: Any, partner: mission.Partner,
                  reply: gri.TaskReply | str, key: tuple | str = ()) -> None:
        v = self.vehicles[robot]
        v.pending.discard(key)
        log.info("%s: %s answered %s", robot, pl.command_name(command) if command >= 0 else command, reply)
        if command == FENCE_JOB:  # outcome: the upload; reply: "" or the reason
            result = mav.MAV_MISSION_ACCEPTED if not reply else mav.MAV_MISSION_DENIED
            if not reply:
                v.stored[mav.MAV_MISSION_TYPE_FENCE] = outcome.items  # type: ignore[union-attr]
            self._mission_ack(v, partner, result, mav.MAV_MISSION_TYPE_FENCE, str(reply))
            return
        assert outcome is not None
        kind = gri.kind_of(outcome.request)
        accepted = not isinstance(reply, str) and reply.accepted
        reason = reply if isinstance(reply, str) else reply.reason
        if command == MISSION_STEP_JOB:  # no COMMAND_ACK (the start's was sent): the verdict told as STATUSTEXT
            if accepted:
                assert not isinstance(reply, str)
                v.started(outcome.role, outcome.offset, reply, outcome.request)
                self._text(v, statustext.Text(mav.MAV_SEVERITY_INFO, f"{v.robot}: {key}"))
            else:
                self._deny(v, f"{key}: {kind} refused: {reason}")
            return
        if command == RTL_LAND_JOB:  # the return's landing: no COMMAND_ACK (the RTL's was sent), the verdict told
            if accepted:
                assert not isinstance(reply, str)
                v.rtl_landing = v.rtl_task = reply.task_id  # shown as RTL until it lands
                self._text(v, statustext.Text(mav.MAV_SEVERITY_INFO, f"{v.robot}: home reached, landing"))
            else:
                v.rtl_landing = None
                self._deny(v, f"home reached, land refused: {reason}")
            return
        if command == REPLACE_JOB:  # a mission uploaded while one flew: its MISSION_ACK is the RAL's verdict
            items, plan_ = v.replacing or ([], None)
            v.replacing = None
            if accepted:
                v.set_plan(items, plan_)
                assert not isinstance(reply, str)
                v.started(outcome.role, outcome.offset, reply, outcome.request)
                self._mission_ack(v, partner, mav.MAV_MISSION_ACCEPTED, mav.MAV_MISSION_TYPE_MISSION)
            else:
                self._mission_ack(v, partner, mav.MAV_MISSION_DENIED, mav.MAV_MISSION_TYPE_MISSION,
                                  f"mission refused: {reason}")
            return
        if accepted:
            assert not isinstance(reply, str)
            v.started(outcome.role, outcome.offset, reply, outcome.request)
            self._ack(v, command, mav.MAV_RESULT_ACCEPTED, partner)
        elif isinstance(reply, str):
            self._ack(v, command, mav.MAV_RESULT_FAILED, partner)
            self._deny(v, f"{kind}: {reason}")
        else:
            self._ack(v, command, mav.MAV_RESULT_DENIED, partner)
            self._deny(v, f"{kind} refused: {reason}")

    def _ack(self, v: Vehicle, command: int, result: int, partner: mission.Partner) -> None:
        self._send(v, mav.MAVLink_command_ack_message(command, result, 0, 0, partner[0], partner[1]))

    def _local(self, v: Vehicle, cmd: cm.Command, outcome: cm.Local, partner: mission.Partner) -> None:
        result = mav.MAV_RESULT_ACCEPTED
        if outcome.what == "speed":
            v.speed = outcome.args[0]
            self._text(v, statustext.Text(mav.MAV_SEVERITY_INFO, f"{v.robot}: the next path flies at "
                                          f"{v.speed:g} m/s"))
        elif outcome.what == "set_current":
            v.mission_index = int(outcome.args[0])
        elif outcome.what == "message_interval":
            entry = mav.mavlink_map.get(int(outcome.args[0]))
            name = entry.msgname if entry is not None else ""
            if not v.schedule.set_interval(name, outcome.args[1]):
                result = mav.MAV_RESULT_UNSUPPORTED
        elif outcome.what == "request_message":
            result = self._request_message(v, int(outcome.args[0]))
        self._ack(v, cmd.command, result, partner)

    def _request_message(self, v: Vehicle, msg_id: int) -> int:
        now = self.clock()
        boot_ms = int((now - v.boot) * 1000) & 0xFFFFFFFF
        if msg_id == mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            self._send(v, mav.MAVLink_autopilot_version_message(CAPABILITIES, 0, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8,
                                                                0, 0, v.sysid))
            return mav.MAV_RESULT_ACCEPTED
        gimbal = {mav.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION: telemetry.gimbal_manager_information,
                  mav.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION: telemetry.gimbal_device_information}.get(msg_id)
        if gimbal is not None:
            if v.state is None or "pan_tilt" not in v.state.available:
                return mav.MAV_RESULT_UNSUPPORTED
            self._send(v, gimbal(boot_ms))
            return mav.MAV_RESULT_ACCEPTED
        entry = mav.mavlink_map.get(msg_id)
        if entry is None or entry.msgname not in telemetry.RATES_HZ or v.state is None:
            return mav.MAV_RESULT_UNSUPPORTED
        msgs = [m for m in self._telemetry(v, entry.msgname, now) if m is not None]
        for m in msgs:
            self._send(v, m)
        return mav.MAV_RESULT_ACCEPTED if msgs else mav.MAV_RESULT_TEMPORARILY_REJECTED

    def _on_gimbal_pitchyaw(self, v: Vehicle, msg: Message, partner: mission.Partner) -> None:
        """GIMBAL_MANAGER_SET_PITCHYAW (a message, not a command: no ACK; a refusal is told as STATUSTEXT)."""
        cmd = cm.Command(mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
                         (math.degrees(msg.pitch), math.degrees(msg.yaw), math.nan, math.nan, 0.0, 0.0, 0.0))
        self._on_command(v, _as_command_long(v.sysid, cmd), partner)

    # ---------------------------------------------------------------- parameters

    def _send_param(self, v: Vehicle, index: int) -> None:
        p = v.spec.params.params[index]
        self._send(v, mav.MAVLink_param_value_message(p.name.encode(), p.value, mav.MAV_PARAM_TYPE_REAL32,
                                                      len(v.spec.params.params), index))

    def _on_param_list(self, v: Vehicle, msg: Message, partner: mission.Partner) -> None:
        v.param_queue = list(range(len(v.spec.params.params)))

    def _on_param_read(self, v: Vehicle, msg: Message, partner: mission.Partner) -> None:
        table = v.spec.params
        if msg.param_index >= 0:
            if msg.param_index < len(table.params):
                self._send_param(v, msg.param_index)
            return
        found = table.find(_param_id(msg.param_id))
        if found is not None:
            self._send_param(v, found[0])

    def _on_param_set(self, v: Vehicle, msg: Message, partner: mission.Partner) -> None:
        name = _param_id(msg.param_id)
        found = v.spec.params.find(name)
        if found is not None:  # the unchanged value tells the ground station the set did not take
            self._send_param(v, found[0])
        self._send(v, mav.MAVLink_param_error_message(partner[0], partner[1], name.encode(),
                                                      found[0] if found else -1,
                                                      mav.MAV_PARAM_ERROR_READ_ONLY if found
                                                      else mav.MAV_PARAM_ERROR_DOES_NOT_EXIST))
        self._deny(v, v.spec.params.refusal(name))

    # ---------------------------------------------------------------- missions

    def _on_mission_count(self, v: Vehicle, msg: Message, partner: mission.Partner) -> None:
        for a in v.transfer.on_count(partner, msg.count, msg.mission_type, self.clock()):
            self._mission_action(v, a)

    def _on_mission_item(self, v: Vehicle, msg: Message, partner: mission.Partner) -> None:
        for a in v.transfer.on_item(partner, pl.item_of(msg), self.clock()):
            self._mission_action(v, a)

    def _on_mission_request_list(self, v: Vehicle, msg: Message, partner: mission.Partner) -> None:
        items = v.download_items() if msg.mission_type == mav.MAV_MISSION_TYPE_MISSION else None
        for a in v.transfer.on_request_list(partner, msg.mission_type, self.clock(), items):
            self._mission_action(v, a)

    def _on_mission_request(self, v: Vehicle, msg: Message, partner: mission.Partner) -> None:
        for a in v.transfer.on_request(partner, msg.seq, msg.mission_type, self.clock()):
            self._mission_action(v, a)

    def _on_mission_ack(self, v: Vehicle, msg: Message, partner: mission.Partner) -> None:
        v.transfer.on_ack(partner, msg.mission_type)

    def _on_mission_clear(self, v: Vehicle, msg: Message, partner: mission.Partner) -> None:
        for a in v.transfer.on_clear(partner, msg.mission_type):
            self._mission_action(v, a)

    def _on_mission_set_current(self, v: Vehicle, msg: Message, partner: mission.Partner) -> None:
        cmd = cm.Command(mav.MAV_CMD_DO_SET_MISSION_CURRENT, (float(msg.seq),) + (0.0,) * 6)
        self._on_command(v, _as_command_long(v.sysid, cmd), partner)

    def _mission_action(self, v: Vehicle, a: mission.Action) -> None:
        if isinstance(a, mission.RequestItem):
            self._send(v, mav.MAVLink_mission_request_int_message(a.partner[0], a.partner[1], a.seq, a.mission_type))
        elif isinstance(a, mission.SendCount):
            self._send(v, mav.MAVLink_mission_count_message(a.partner[0], a.partner[1], a.count, a.mission_type))
        elif isinstance(a, mission.SendItem):
            it = a.item
            self._send(v, mav.MAVLink_mission_item_int_message(
                a.partner[0], a.partner[1], it.seq, it.frame, it.command, int(it.seq == 0), it.autocontinue,
                it.param1, it.param2, it.param3, it.param4, it.x, it.y, it.z, it.mission_type))
        elif isinstance(a, mission.Ack):
            self._mission_ack(v, a.partner, a.result, a.mission_type, a.reason)
        elif isinstance(a, mission.Uploaded):
            self._uploaded(v, a)
        elif isinstance(a, mission.Cleared):
            self._cleared(v, a)

    def _mission_ack(self, v: Vehicle, partner: mission.Partner, result: int, mission_type: int,
                     reason: str = "") -> None:
        self._send(v, mav.MAVLink_mission_ack_message(partner[0], partner[1], result, mission_type))
        if result != mav.MAV_MISSION_ACCEPTED and reason:
            self._deny(v, reason)

    def _uploaded(self, v: Vehicle, a: mission.Uploaded) -> None:
        if a.mission_type == mav.MAV_MISSION_TYPE_MISSION:
            if not a.items:
                v.set_plan([], None)
                self._mission_ack(v, a.partner, mav.MAV_MISSION_ACCEPTED, a.mission_type)
                return
            try:
                plan = pl.plan_of(a.items, v.state.home.alt if v.state and v.state.home else None)
            except pl.PlanError as exc:
                self._mission_ack(v, a.partner, mav.MAV_MISSION_UNSUPPORTED, a.mission_type, str(exc))
                return
            if not v.mission_running():
                v.set_plan(a.items, plan)
                self._mission_ack(v, a.partner, mav.MAV_MISSION_ACCEPTED, a.mission_type)
                return
            # replace means replace: a mission uploaded while the last one flies replaces the path being flown (the
            # RAL admits it as any path); the MISSION_ACK waits for its verdict
            v.replacing = (a.items, plan)
            request = gri.FollowPath(waypoints=list(plan.waypoints), speed=plan.speed or v.speed)
            self.workers[v.robot].jobs.put((v.robot, REPLACE_JOB, cm.Send(request, "mission", 0), a.partner, ()))
        elif a.mission_type == mav.MAV_MISSION_TYPE_FENCE:
            self._fence(v, a)
        else:
            self._mission_ack(v, a.partner, mav.MAV_MISSION_UNSUPPORTED, a.mission_type,
                              "rally points are not mapped (a cromat robot returns to its take-off point)")

    def _fence(self, v: Vehicle, a: mission.Uploaded) -> None:
        try:
            puts = fence.zones_of(v.robot, a.items, self.gcs.name)
        except pl.PlanError as exc:
            self._mission_ack(v, a.partner, mav.MAV_MISSION_UNSUPPORTED, a.mission_type, str(exc))
            return
        threading.Thread(target=self._apply_fence, args=(v.robot, a, puts), daemon=True).start()

    def _apply_fence(self, robot: str, a: mission.Uploaded, puts: list[Any]) -> None:
        """Off the loop (world requests wait for the RAL): the old zones of this vehicle out, the new ones in. Always
        answered: whatever goes wrong is the upload's refusal, with its reason (else the ground station times out)."""
        try:
            from bbcs.contracts import world as w
            from ral.gcs.fleet_cmd import world_request, world_snapshot

            old = [e.id for e in world_snapshot(self.gcs, robot).entries
                   if e.id.startswith(fence.fence_id(robot, 0)[:-1]) and not e.deleted]
            for entry_id in old:
                world_request(self.gcs, robot, w.WorldDelete(id=entry_id, author=self.gcs.name), self.signer)
            for put in puts:
                reply = world_request(self.gcs, robot, put, self.signer)
                if not reply.accepted:
                    raise GcsError(f"zone {put.id} refused: {reply.reason}")
        except GcsError as exc:
            reason = f"fence upload refused: {exc} (the robot has no world model, or it refused the zone)"
            self.inbox.put(("reply", (robot, FENCE_JOB, a, a.partner, reason)))
            return
        except Exception as exc:  # noqa: BLE001 - a fault of the gateway's side: logged, and the upload refused
            log.exception("fence upload for %s", robot)
            self.inbox.put(("reply", (robot, FENCE_JOB, a, a.partner, f"fence upload failed in the gateway: {exc}")))
            return
        self.inbox.put(("reply", (robot, FENCE_JOB, a, a.partner, "")))

    def _cleared(self, v: Vehicle, a: mission.Cleared) -> None:
        if a.mission_type == mav.MAV_MISSION_TYPE_FENCE:  # the vehicle's zones leave the world model
            self._fence(v, mission.Uploaded(a.partner, [], a.mission_type))
            return
        if a.mission_type == mav.MAV_MISSION_TYPE_MISSION:
            v.set_plan([], None)
        v.stored.pop(a.mission_type, None)
        self._mission_ack(v, a.partner, mav.MAV_MISSION_ACCEPTED, a.mission_type)


def _command_key(cmd: cm.Command) -> tuple:
    """A command and its parameters, NaN included (NaN != NaN), to know a resend from a new command."""
    return (cmd.command, cmd.frame, *(None if math.isnan(x) else x for x in cmd.params))


def _param_id(raw: Any) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).rstrip("\x00")


def _as_command_long(sysid: int, cmd: cm.Command) -> Message:
    p = cmd.params
    return mav.MAVLink_command_long_message(sysid, mav.MAV_COMP_ID_AUTOPILOT1, cmd.command, 0, *p)


_HANDLERS: dict[str, Callable[[Gateway, Vehicle, Message, mission.Partner], None]] = {
    "COMMAND_LONG": Gateway._on_command,
    "COMMAND_INT": Gateway._on_command,
    "PARAM_REQUEST_LIST": Gateway._on_param_list,
    "PARAM_REQUEST_READ": Gateway._on_param_read,
    "PARAM_SET": Gateway._on_param_set,
    "MISSION_COUNT": Gateway._on_mission_count,
    "MISSION_ITEM_INT": Gateway._on_mission_item,
    "MISSION_ITEM": Gateway._on_mission_item,
    "MISSION_REQUEST_LIST": Gateway._on_mission_request_list,
    "MISSION_REQUEST_INT": Gateway._on_mission_request,
    "MISSION_REQUEST": Gateway._on_mission_request,
    "MISSION_ACK": Gateway._on_mission_ack,
    "MISSION_CLEAR_ALL": Gateway._on_mission_clear,
    "MISSION_SET_CURRENT": Gateway._on_mission_set_current,
    "GIMBAL_MANAGER_SET_PITCHYAW": Gateway._on_gimbal_pitchyaw,
}
