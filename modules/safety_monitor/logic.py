"""What the flight-safety monitor decides, with no bus and no clock: observations in, breaches out.

Every ``on_*`` call takes ``now``, the robot's clock when the observation arrived (the module passes its clock;
tests pass numbers), and every stamp it is given is on that same clock (the module converts them:
:mod:`modules.safety_monitor.clocks`). Observations arrive in any order across their sources (a command's batch
reaches the DSP before the RAL announces the task it serves), so a judgement waits until what could excuse it has
had time to arrive, and ``tick(now)`` returns the breaches decided since the last call. Each episode (one command,
one task, one excursion) gives at most one breach.

Position sources: the simulator's truth when it is flowing (simulation), else the DSP telemetry (a real robot);
the GRI is judged against the truth only (there is no truth on a real robot).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from bbcs.contracts import dsp as p
from bbcs.contracts.dsp import DspSent
from bbcs.contracts.error_codes import RalErrorCode, UquadErrorCode
from bbcs.contracts.gri import GriEvent, GriState
from bbcs.contracts.mri import EFFECT_LOST, reported_error
from bbcs.contracts.robot import RobotTelemetry
from bbcs.contracts.safety import Breach, Invariant, Severity
from bbcs.contracts.tasks import FollowPath, Goto, TakeOff, TaskInfo
from bbcs.contracts.vehicle_truth import VehicleTruth
from bbcs.geodesy import distance_m

DEFAULT_SERVES: Mapping[str, frozenset[str]] = {
    "path_follower": frozenset({"movement"}),
    "pan_tilt": frozenset({"pan_tilt", "perception"}),
}
"""Sender (the DSP command key's) → task types whose tasks may be behind its commands (the UAV manifests: the path
follower serves movement tasks, the pan & tilt serves pan & tilt tasks and perception's ``track``)."""
GOAL_KINDS = frozenset({"goto", "follow_path", "survey", "orbit"})
"""Task kinds that end at a place: their goal is the last waypoint the DSP was sent while they ran."""
CLIMB_KINDS = frozenset({"take_off", "land"})
"""Movement that crosses MIN_CLEARANCE on purpose."""
LOSS_OF_CONTROL_CODES = frozenset({int(RalErrorCode.LOSS_OF_CONTROL), int(UquadErrorCode.LOSS_OF_CONTROL)})
"""The RAL's loss of control from the telemetry (604) and the uQuad flight module's tumble cut (706)."""
SKEW_S = 0.05
MAX_SENT = 50_000
"""Clock difference tolerated between the processes that stamp a task and a command (one machine)."""


def is_stop(cmd: object) -> bool:
    """A command that commands no motion: empty the queue, stop, hold the gimbal where it is."""
    return (isinstance(cmd, p.Abort | p.InvalidatePath)
            or (isinstance(cmd, p.SetTracking) and not cmd.enable)
            or (isinstance(cmd, p.SetSpeed) and cmd.speed == 0.0)
            or (isinstance(cmd, p.SetPanTiltMode) and cmd.mode == p.PanTiltMode.HOLD))


def is_mode_restore(cmd: object) -> bool:
    """A command that sets the gimbal's mode only: what the manager's restore of the pan & tilt mode slot (manifest
    ``restore = true``) makes the module send when a task of its types ends, or when the module restarts after a
    task failed with it. It points nothing by itself and moves no aircraft."""
    return isinstance(cmd, p.SetPanTiltMode)


def command_severity(cmd: object) -> Severity:
    """An untraced command that moves the aircraft is critical, one that moves the gimbal an error, a stop a
    warning."""
    if is_stop(cmd):
        return Severity.WARNING
    if isinstance(cmd, p.SetPanTiltMode | p.SetPanTiltAngles | p.SetPanTiltTarget | p.Ping | p.ClearError):
        return Severity.ERROR
    return Severity.CRITICAL


def describe_command(cmd: object) -> str:
    fields = ", ".join(f"{k}={getattr(cmd, k)!r}" for k in getattr(cmd, "__struct_fields__", ()))
    return f"{type(cmd).__name__}({fields})"


def robot_fault(info: TaskInfo) -> bool:
    """Whether ``info`` failed because the robot lost the means to carry it out, whatever the aircraft was doing: a
    module it relies on exited (the manager's wording, ``mri.EFFECT_LOST``), or the DSP reported one of its own
    flight faults (GPS lost, low battery, rotor speed, a sensor: ``dsp.FLIGHT_FAULTS``, forwarded as 1000 + code and
    failed on by the RAL in ``mri.module_error_detail``'s wording)."""
    if info.status != "failed":
        return False
    code = reported_error(info.detail)
    return info.detail.endswith(EFFECT_LOST) or (
        code is not None and code - p.FORWARDED_DSP_ERROR_BASE in p.FLIGHT_FAULTS)


def judged_invariants(dsp_commands: bool, truth: bool) -> frozenset[Invariant]:
    """The invariants the monitor can judge on a robot: 1 and 4 are about DSP commands (none on a uQuad, whose
    flight module drives its motors itself), 3 needs the simulator's truth (simulation only); 2 and 5 are judged
    from the truth, else the DSP telemetry (on a uQuad without truth: nothing to judge them on)."""
    out = {Invariant.TASK_VERDICT, Invariant.ENVELOPE}
    if dsp_commands:
        out |= {Invariant.COMMAND_TRACED, Invariant.ABORT_LATENCY}
    if truth:
        out.add(Invariant.GRI_TRUTH)
    elif not dsp_commands:
        out -= {Invariant.TASK_VERDICT, Invariant.ENVELOPE}
    return frozenset(out)


VEHICLES: Mapping[str, Mapping[str, bool]] = {
    "uav": {"dsp_commands": True, "gri_airborne_is_motors": False},
    "uquad": {"dsp_commands": False, "gri_airborne_is_motors": True},
}
"""What a robot kind means for the monitor (:class:`MonitorConfig`'s fields): the UAV flies through a DSP whose
airborne flag flips at lift-off; the uQuad has no DSP and says airborne while its motors run."""


def ground_distance_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Horizontal metres between two points (bbcs.geodesy: the model every other process uses)."""
    return distance_m(lat1, lon1, lat2, lon2)


@dataclass(frozen=True)
class MonitorConfig:
    robot: str
    geofence: tuple[float, float, float] | None = None
    """Centre latitude, longitude (degrees), radius (m): the robot .conf's GEOFENCE."""
    min_clearance_m: float | None = None
    """The robot .conf's MIN_CLEARANCE, metres above the take-off point."""
    serves: Mapping[str, frozenset[str]] = field(default_factory=lambda: dict(DEFAULT_SERVES))
    moving_types: frozenset[str] = frozenset({"movement"})
    """Task types that fly the aircraft: invariant 2 judges their failures by the aircraft's progress. A pan & tilt
    or tracking task fails with its gimbal, whatever the aircraft flies meanwhile for another task (campaign seed 41,
    sequence 113: a look-at failed when the pan & tilt was killed, during a goto)."""
    dsp_commands: bool = True
    """Whether the robot flies through a DSP (the UAV): its commands are judged (invariant 1), an abort must reach
    it (invariant 4) and a goal may be the DSP's grid point. A uQuad has none (:func:`judged_invariants`)."""
    gri_airborne_is_motors: bool = False
    """The robot's ``airborne`` means its motors run (the uQuad: its planner is not idle, docs/uquad.md §5, from the
    take-off's motor ramp on the ground to the landing's stop), not that it is off the ground (the UAV's DSP flag):
    then only ``airborne=False`` while the truth is surely in the air is wrong (motors off in the air)."""
    monitor_name: str = "safety_monitor"
    """Errors this module itself reported never count as the robot reporting a loss of control."""
    decide_after_s: float = 3.0
    """A command is judged once the task book is this much newer than it, or this long after it at the latest."""
    book_lag_s: float = 0.3
    end_grace_s: float = 2.0
    """A stop command this soon after a task of its sender's types ended is that task's end (the hold that ends it);
    so is a pan & tilt mode command (the mode restored at its end, :func:`is_mode_restore`)."""
    goal_tolerance_m: float = 10.0
    """Horizontal: the DSP gets waypoints on a 1e-4 degree grid (about 11 m), the RAL completes within 8 m."""
    goal_alt_tolerance_m: float = 3.0
    verdict_wait_s: float = 0.5
    lost_stop_s: float = 15.0
    """A task failed on a robot fault (:func:`robot_fault`): by this long after, the aircraft must have stopped flying
    it (the hold sent at the failure, or the restarted DSP link's start-up, stops it). Judged on the
    ``lost_window_s`` before."""
    lost_window_s: float = 5.0
    progress_window_s: float = 10.0
    progress_m: float = 2.0
    gri_position_m: float = 5.0
    gri_lag_s: float = 0.5
    truth_wait_s: float = 2.0
    """How long after a GRI stamp's window the truth of it may still be on its way (then judged on what came)."""
    """How long before its stamp a GRI position may have been measured (the DSP → telemetry module pipeline)."""
    airborne_window_s: float = 2.0
    airborne_height_m: float = 1.0
    """Truth height above which the aircraft is surely airborne (the simulator's flag flips at 0.2 m)."""
    ground_height_m: float = 0.2
    loc_attitude_deg: float = 60.0
    loc_spin_deg_s: float = 200.0
    loc_impact_m_s: float = 2.0
    loc_report_s: float = 1.0
    loc_fail_window_s: float = 3.0
    """A task failed on a loss of control the truth showed begun at most this long before (the robot's report is due
    within ``loc_report_s``, the task's end follows it) failed on a robot fault."""
    loc_lead_s: float = 0.5
    """... or begun at most this long after: the robot may know first (the uQuad's flight module reports 706 for a
    motor it sees stop; the truth's attitude crossed the monitor's threshold 60 ms after the RAL failed the task on
    it, once the RAL judged each state as it came)."""
    report_wait_s: float = 2.5
    """How long after the 1 s window a report may take to reach the monitor (the GRI state comes once a second)."""
    abort_latency_s: float = 0.1
    abort_wait_s: float = 2.0
    envelope_debounce_s: float = 1.0
    history_s: float = 60.0
    stamp_lag_s: float = 0.0
    """How much later than a process's stamp the physics it describes may be. 0 on a robot (one wall clock);
    in a lockstep simulation one frame (``step_s``): a process's clock moves to a frame's time when the frame
    ends, and the telemetry the frame produced may reach it before that (stamped with the previous frame's time),
    while the truth is stamped with the physics' own time."""


@dataclass
class _Sent:
    msg: DspSent
    seen: float


@dataclass
class _Sample:
    """One position of the aircraft: from the truth or the DSP telemetry, stamped with the robot clock."""

    t: float
    lat: float
    lon: float
    alt: float
    airborne: bool | None = None
    height: float | None = None
    queue: int | None = None
    nav: tuple[float, float, float] | None = None
    nav_distance: float | None = None


@dataclass
class _Episode:
    since: float
    reported: bool = False
    evidence: list[str] = field(default_factory=list)


class SafetyMonitor:
    """Folds observations; ``tick`` returns the breaches it has decided (each once)."""

    def __init__(self, cfg: MonitorConfig) -> None:
        self.cfg = cfg
        self.tasks: dict[tuple[float, int], TaskInfo] = {}
        """(task book epoch, task id) → its latest record: a restarted manager numbers its tasks again."""
        self.book_stamp: float | None = None
        self.sent: deque[_Sent] = deque(maxlen=MAX_SENT)
        """Commands by count, not age: a survey's goal is the last waypoint sent since it started."""
        self._pending: list[_Sent] = []
        self._verdicts_due: dict[tuple[float, int], float] = {}
        self._aborts_due: set[tuple[float, int]] = set()
        self._judged_tasks: set[tuple[float, int]] = set()
        self.truth: deque[tuple[float, VehicleTruth]] = deque()
        self.telemetry: deque[_Sample] = deque()
        self.home_alt: float | None = None
        self._reports: deque[tuple[float, str]] = deque()
        """(stamp, what): errors and failure events the robot told its ground stations."""
        self._loc: _Episode | None = None
        self._loc_ok_since: float | None = None
        self._loc_starts: deque[float] = deque(maxlen=100)
        """When each loss of control the truth showed began."""
        self._gri_pos: _Episode | None = None
        self._gri_air: _Episode | None = None
        self._gri_pending: deque[RobotTelemetry] = deque(maxlen=1000)
        """GRI telemetry not yet compared with the truth (waiting for the truth of its window)."""
        self._fence: _Episode | None = None
        self._clear: _Episode | None = None
        self._out: list[Breach] = []
        self.counts: dict[str, int] = {"commands": 0, "commands_judged": 0, "telemetry": 0, "truth": 0,
                                       "verdicts": 0, "gri_states": 0, "books": 0, "gri_compared": 0}
        self.breach_counts: dict[str, int] = {}

    # ------------------------------------------------------------------ observations

    def on_sent(self, now: float, msg: DspSent) -> None:
        item = _Sent(msg, now)
        self.sent.append(item)
        self._pending.append(item)
        self.counts["commands"] += 1

    def on_book(self, now: float, stamp: float, active: Iterable[TaskInfo], ended: Iterable[TaskInfo],
                epoch: float = 0.0) -> None:
        """The Module Manager's task book (running tasks and the recently ended ones)."""
        self.counts["books"] += 1
        self.book_stamp = stamp if self.book_stamp is None else max(self.book_stamp, stamp)
        for info in [*active, *ended]:
            key = (epoch, info.id)
            old = self.tasks.get(key)
            if old is not None and old.ended is not None:
                continue  # an ended record never changes
            self.tasks[key] = info
            if info.name == "abort" and self.cfg.dsp_commands and key not in self._judged_tasks:
                self._aborts_due.add(key)
            if info.ended is not None and key not in self._judged_tasks:
                wait = self.cfg.lost_stop_s if robot_fault(info) else self.cfg.verdict_wait_s
                self._verdicts_due[key] = info.ended + wait

    def on_telemetry(self, now: float, t: p.Telemetry) -> None:
        """The DSP's telemetry (the position source when no truth flows)."""
        self.counts["telemetry"] += 1
        if t.position is None:
            return
        st = t.status
        airborne = st.airborne if st is not None else None
        if airborne is False:
            self.home_alt = t.position.alt if self.home_alt is None or not self.truth else self.home_alt
        nav = t.nav if t.nav is not None and t.nav.active else None
        sample = _Sample(now, t.position.lat, t.position.lon, t.position.alt, airborne=airborne,
                         queue=st.queue_length if st is not None else None,
                         nav=(nav.lat, nav.lon, nav.alt) if nav else None,
                         nav_distance=nav.distance if nav else None)
        self.telemetry.append(sample)
        self._trim(self.telemetry, now, lambda s: s.t)
        if not self._truth_flowing(now):
            height = sample.alt - self.home_alt if self.home_alt is not None else None
            sample.height = height
            self._envelope(now, sample, "DSP telemetry")

    def on_truth(self, now: float, truth: VehicleTruth) -> None:
        """The simulator's true state (simulation only)."""
        self.counts["truth"] += 1
        prev = self.truth[-1][1] if self.truth else None
        self.truth.append((now, truth))
        self._trim(self.truth, now, lambda s: s[0])
        self.home_alt = truth.home[2]
        height = truth.alt - truth.home[2]
        airborne = height > self.cfg.ground_height_m
        self._envelope(now, _Sample(now, truth.lat, truth.lon, truth.alt, airborne=airborne, height=height), "truth")
        self._watch_control(now, truth, prev, height)

    def on_gri_state(self, now: float, state: GriState) -> None:
        self.counts["gri_states"] += 1
        for e in state.errors:
            if e.module != self.cfg.monitor_name:
                self._note_report(e.stamp, f"GRI error {e.module} {e.code} {e.name} at {e.stamp:.2f}: {e.detail}")
        tel = state.telemetry
        if tel is None or tel.position is None:
            return
        self._gri_pending.append(tel)

    def _judge_gri(self, now: float) -> None:
        """Each GRI telemetry against the truth once the truth covers its window (the truth of a frame may reach
        the monitor after the GRI state stamped at its start), or ``truth_wait_s`` after it with what there is."""
        latest = self.truth[-1][0] if self.truth else None
        while self._gri_pending:
            tel = self._gri_pending[0]
            end = tel.stamp + SKEW_S + self.cfg.stamp_lag_s
            if (latest is None or latest < end) and now < end + self.cfg.truth_wait_s:
                return
            self._gri_pending.popleft()
            self._compare_gri(tel)

    def _compare_gri(self, tel: RobotTelemetry) -> None:
        if not self.truth or tel.position is None:
            return
        # the telemetry's stamp is when the telemetry module converted the DSP's frame, a little after the DSP
        # measured it: the GRI is right if the aircraft was there at some instant of the lag before its stamp
        window = [tr for s, tr in self.truth
                  if tel.stamp - self.cfg.gri_lag_s <= s <= tel.stamp + SKEW_S + self.cfg.stamp_lag_s]
        if not window:
            return
        self.counts["gri_compared"] += 1
        pos = tel.position
        d, truth = min(((math.hypot(ground_distance_m(pos.lat, pos.lon, tr.lat, tr.lon), pos.alt - tr.alt), tr)
                        for tr in window), key=lambda x: x[0])
        ev = [f"GRI telemetry at {tel.stamp:.2f}: {pos.lat:.7f}, {pos.lon:.7f}, {pos.alt:.1f} m",
              f"truth nearest to it in the {self.cfg.gri_lag_s:g} s before"
              + (f" (and {self.cfg.stamp_lag_s:g} s after)" if self.cfg.stamp_lag_s else "")
              + f": {truth.lat:.7f}, {truth.lon:.7f}, "
              f"{truth.alt:.1f} m", f"distance {d:.1f} m (limit {self.cfg.gri_position_m:g} m)"]
        self._gri_pos = self._episode(self._gri_pos, d > self.cfg.gri_position_m, tel.stamp, 0.0,
                                      Invariant.GRI_TRUTH, "gri_position", Severity.ERROR,
                                      f"the GRI shows the aircraft {d:.1f} m from where it is", ev)
        if tel.airborne is not None:
            expected = self._truth_airborne(tel.stamp)
            wrong = expected is not None and expected != tel.airborne \
                and not (self.cfg.gri_airborne_is_motors and (tel.airborne or self._cut_after_loss(tel.stamp)))
            ev = [f"GRI telemetry at {tel.stamp:.2f}: airborne={tel.airborne}",
                  f"truth over the {self.cfg.airborne_window_s:g} s before"
                  + (f" (to {self.cfg.stamp_lag_s:g} s after)" if self.cfg.stamp_lag_s else "")
                  + f": airborne={expected}"]
            self._gri_air = self._episode(self._gri_air, wrong, tel.stamp, 0.0, Invariant.GRI_TRUTH, "gri_airborne",
                                          Severity.ERROR, f"the GRI says airborne={tel.airborne}, the truth "
                                          f"{expected}", ev)

    def on_gri_event(self, now: float, event: GriEvent) -> None:
        if event.kind in ("task_failed", "failsafe", "aborted"):
            self._note_report(event.stamp, f"GRI event {event.kind} task {event.task_id} at {event.stamp:.2f}: "
                                           f"{event.detail}")

    # ------------------------------------------------------------------ decisions

    def tick(self, now: float) -> list[Breach]:
        self._judge_gri(now)
        self._judge_commands(now)
        self._judge_verdicts(now)
        self._judge_aborts(now)
        self._judge_loss_of_control(now)
        out, self._out = self._out, []
        return out

    def _breach(self, invariant: Invariant, kind: str, severity: Severity, stamp: float, summary: str,
                evidence: list[str], task_id: int = 0) -> None:
        self.breach_counts[kind] = self.breach_counts.get(kind, 0) + 1
        self._out.append(Breach(robot=self.cfg.robot, invariant=invariant, kind=kind, severity=severity,
                                stamp=stamp, summary=summary, evidence=evidence, task_id=task_id))

    # 1. every command traced to a task, the failsafe or the start-up
    def _judge_commands(self, now: float) -> None:
        keep: list[_Sent] = []
        for item in self._pending:
            c = item.msg.stamp
            ready = (self.book_stamp is not None and self.book_stamp >= c + self.cfg.book_lag_s) \
                or now >= max(c, item.seen) + self.cfg.decide_after_s
            if not ready:
                keep.append(item)
                continue
            self.counts["commands_judged"] += 1
            why = self.behind(item.msg)
            if why is None:
                self._untraced(item.msg)
        self._pending = keep

    def behind(self, msg: DspSent) -> str | None:
        """What is behind a sent command (None: nothing)."""
        types = self.cfg.serves.get(msg.sender, frozenset())
        c = msg.stamp
        for info in self.tasks.values():  # in lockstep the sender's clock may still read the frame before the
            # manager's (it moves when its loop takes the frame's ask): a command up to a frame early is the task's
            if info.task_type in types and info.started - SKEW_S - self.cfg.stamp_lag_s <= c \
                    and (info.ended is None or c <= info.ended + SKEW_S):
                return f"task {info.id} {info.name} ({info.origin})"
        if is_stop(msg.command) or is_mode_restore(msg.command):
            for info in self.tasks.values():
                if info.task_type in types and info.ended is not None \
                        and info.ended - SKEW_S <= c <= info.ended + self.cfg.end_grace_s:
                    return f"the end of task {info.id} {info.name}"
            first = min((i.started for i in self.tasks.values()), default=None)
            if first is None or c < first:
                return "the start-up sequence"
            if msg.batch_id == 1:  # batch ids count from 1 in each process of a module
                return f"the start-up of a new {msg.sender} process (its first batch: the mode the manager keeps)"
        return None

    def _untraced(self, msg: DspSent) -> None:
        types = sorted(self.cfg.serves.get(msg.sender, frozenset()))
        cmd = describe_command(msg.command)
        before = [i for i in self.tasks.values() if i.ended is not None and i.ended <= msg.stamp]
        last = max(before, key=lambda i: i.ended or 0.0, default=None)
        live = [i for i in self.tasks.values() if i.ended is None or i.ended >= msg.stamp]
        ev = [f"DSP sent {cmd} from {msg.sender!r} (batch {msg.batch_id}) at {msg.stamp:.3f}",
              f"{msg.sender!r} serves task types: {', '.join(types) or 'none'}",
              "tasks running then: " + (", ".join(f"{i.id} {i.name} ({i.task_type})" for i in live
                                                 if i.started <= msg.stamp) or "none")]
        if last is not None:
            ev.append(f"last task ended before it: {last.id} {last.name} {last.status} at {last.ended:.3f} "
                      f"({msg.stamp - (last.ended or 0.0):.2f} s before): {last.detail}")
        self._breach(Invariant.COMMAND_TRACED, "untraced_command", command_severity(msg.command), msg.stamp,
                     f"{cmd} reached the DSP with no task, failsafe or start-up behind it", ev)

    # 2. a task completes only at its goal, and is never failed while the aircraft progresses
    def _judge_verdicts(self, now: float) -> None:
        for task_id, due in list(self._verdicts_due.items()):
            if now < due:
                continue
            del self._verdicts_due[task_id]
            self._judged_tasks.add(task_id)
            info = self.tasks[task_id]
            self.counts["verdicts"] += 1
            if info.status == "completed":
                self._judge_completed(info)
            elif info.status == "failed":
                self._judge_failed(info)

    def goal(self, info: TaskInfo) -> tuple[float, float, float] | None:
        """Where a task that ends at a place must end: the last waypoint the DSP was sent while it ran, else the
        last of its parameters' waypoints. In lockstep a waypoint stamped in the very frame the task ended came
        after its end (the next task's: stamps are exact to the frame, and the end is what let the next task
        start), so only those before it count there."""
        end = info.ended if info.ended is not None else math.inf
        last = None
        for s in self.sent:
            c = s.msg.stamp
            before_end = c < end if self.cfg.stamp_lag_s else c <= end + SKEW_S
            if isinstance(s.msg.command, p.AddWaypoint) and info.started - SKEW_S <= c and before_end:
                last = s.msg.command
        if last is not None:
            return (last.lat, last.lon, last.alt)
        if isinstance(info.params, Goto | FollowPath):
            w = info.params.waypoints[-1]
            return (w.lat, w.lon, w.alt)
        return None

    def _judge_completed(self, info: TaskInfo) -> None:
        """Right if the aircraft was at the goal at the completion's stamp (within the stamp's frame: a robot-clock
        stamp may be a frame earlier than the physics the RAL judged on); else a breach with the nearest miss."""
        assert info.ended is not None
        judged = [j for j in (self._completed_at(info, pos, source) for pos, source in self._positions_at(info.ended))
                  if j is not None]
        if not judged or any(wrong is None for wrong, _ in judged):
            return
        wrong, ev = judged[0]
        if len(judged) > 1:
            ev.append(f"nor at any of the {len(judged) - 1} other truth samples up to {self.cfg.stamp_lag_s:g} s "
                      "after it")
        self._breach(Invariant.TASK_VERDICT, "completed_away_from_goal", Severity.ERROR, info.ended,
                     f"task {info.id} {info.name}: {wrong}", ev, info.id)

    def _completed_at(self, info: TaskInfo, pos: _Sample, source: str) -> tuple[str | None, list[str]] | None:
        """(what is wrong with ``info`` completed at ``pos`` or None, evidence); None: not judged."""
        ev = [f"task {info.id} {info.name} ({info.kind or '-'}) completed at {info.ended:.3f}: {info.detail}",
              f"{source} at {pos.t:.3f}: {pos.lat:.7f}, {pos.lon:.7f}, {pos.alt:.1f} m, airborne={pos.airborne}"]
        wrong = None
        if info.kind == "take_off" and isinstance(info.params, TakeOff) and self.home_alt is not None:
            height = pos.alt - self.home_alt
            ev.append(f"height {height:.1f} m, asked {info.params.height:g} m")
            if height < info.params.height - self.cfg.goal_alt_tolerance_m:
                wrong = f"take-off completed at {height:.1f} m of {info.params.height:g} m"
        elif info.kind == "land":
            if pos.airborne:
                wrong = "land completed while airborne"
        elif info.kind in GOAL_KINDS or info.name in GOAL_KINDS:
            goal = self.goal(info)
            if goal is None:
                return None
            # the DSP flies to the waypoint as its protocol carries it (degrees x 10^4): either is the goal
            q = (round(goal[0] * p.LATLON_SCALE) / p.LATLON_SCALE, round(goal[1] * p.LATLON_SCALE) / p.LATLON_SCALE) \
                if self.cfg.dsp_commands else goal  # no DSP (a uQuad): the goal as the task gave it
            d = min(ground_distance_m(pos.lat, pos.lon, goal[0], goal[1]),
                    ground_distance_m(pos.lat, pos.lon, q[0], q[1]))
            dz = abs(pos.alt - goal[2])
            ev.append(f"goal {goal[0]:.7f}, {goal[1]:.7f}, {goal[2]:.1f} m: {d:.1f} m away, {dz:.1f} m above/below "
                      f"(tolerance {self.cfg.goal_tolerance_m:g} m, {self.cfg.goal_alt_tolerance_m:g} m)")
            if d > self.cfg.goal_tolerance_m or dz > self.cfg.goal_alt_tolerance_m:
                wrong = f"completed {d:.1f} m from its goal ({dz:.1f} m in height)"
        else:
            return None
        return wrong, ev

    def progress(self, start: float, end: float, kind: str = "",
                 goal: tuple[float, float, float] | None = None) -> list[str]:
        """How the aircraft progressed in [start, end] by the DSP's own account (empty: it did not): waypoints
        reached (the queue shortened), the distance to the same nav target shrinking, the height changing. A robot
        without a DSP (a uQuad): by the truth, the distance to the task's ``goal`` shrinking, the height changing
        (:meth:`truth_progress`)."""
        window = [s for s in self.telemetry if start <= s.t <= end]
        if len(window) < 2:
            return [] if self.cfg.dsp_commands else self.truth_progress(start, end, kind, goal)
        first, last = window[0], window[-1]
        seen = []
        if first.queue is not None and last.queue is not None and last.queue < first.queue:
            seen.append(f"waypoint queue {first.queue} -> {last.queue}")
        same = [s for s in window if s.nav is not None and s.nav == last.nav and s.nav_distance is not None]
        if len(same) >= 2 and same[0].nav_distance - same[-1].nav_distance >= self.cfg.progress_m:  # type: ignore[operator]
            seen.append(f"distance to the nav target {same[0].nav_distance:.1f} -> {same[-1].nav_distance:.1f} m")
        if kind in CLIMB_KINDS and abs(last.alt - first.alt) >= self.cfg.progress_m:
            seen.append(f"altitude {first.alt:.1f} -> {last.alt:.1f} m")
        return seen

    def truth_progress(self, start: float, end: float, kind: str = "",
                       goal: tuple[float, float, float] | None = None) -> list[str]:
        """Progress in [start, end] by the truth (a robot with no DSP telemetry): the distance to ``goal`` shrank by
        ``progress_m``, or (take-off, landing) the height changed by it."""
        window = [tr for s, tr in self.truth if start <= s <= end]
        if len(window) < 2:
            return []
        first, last = window[0], window[-1]
        seen = []
        if goal is not None:
            def dist(tr: VehicleTruth) -> float:
                return math.hypot(ground_distance_m(tr.lat, tr.lon, goal[0], goal[1]), tr.alt - goal[2])

            d0, d1 = dist(first), dist(last)
            if d0 - d1 >= self.cfg.progress_m:
                seen.append(f"distance to the goal {d0:.1f} -> {d1:.1f} m (truth)")
        if kind in CLIMB_KINDS and abs(last.alt - first.alt) >= self.cfg.progress_m:
            seen.append(f"altitude {first.alt:.1f} -> {last.alt:.1f} m (truth)")
        return seen

    def _judge_failed(self, info: TaskInfo) -> None:
        """Invariant 2: a task is never failed while the aircraft makes progress. A task failed on a robot fault
        (:func:`robot_fault`: a module it relies on exited, the DSP's own flight fault) is failed whatever the
        aircraft did: the robot can no longer carry it out safely. Then what matters is that the aircraft stops
        flying it instead of flying on with nobody commanding it."""
        assert info.ended is not None
        if info.task_type not in self.cfg.moving_types:
            return  # the aircraft's progress is another task's
        if robot_fault(info) or self._confirmed_loss_of_control(info):
            end = info.ended + self.cfg.lost_stop_s
            if any(o.task_type == info.task_type and o.id != info.id and info.ended <= o.started < end
                   for o in self.tasks.values()):
                return  # a new task of its type took over before the aircraft was due to have stopped (in lockstep
                # it may start in the failure's own frame, stamped alike: campaign seed 41, sequence 64)
            seen = self.progress(end - self.cfg.lost_window_s, end, info.kind or info.name, self._goal_of(info))
            if seen:
                ev = [f"task {info.id} {info.name} failed at {info.ended:.3f}: {info.detail}",
                      f"{self.cfg.lost_stop_s - self.cfg.lost_window_s:g}-{self.cfg.lost_stop_s:g} s after "
                      f"({self._progress_source}): " + "; ".join(seen)]
                self._breach(Invariant.TASK_VERDICT, "flew_on_after_failure", Severity.ERROR, info.ended,
                             f"task {info.id} {info.name} failed on a robot fault, and the aircraft flew on", ev,
                             info.id)
            return
        seen = self.progress(info.ended - self.cfg.progress_window_s, info.ended, info.kind or info.name,
                             self._goal_of(info))
        if seen:
            ev = [f"task {info.id} {info.name} failed at {info.ended:.3f}: {info.detail}",
                  f"in the {self.cfg.progress_window_s:g} s before ({self._progress_source}): " + "; ".join(seen)]
            self._breach(Invariant.TASK_VERDICT, "failed_while_progressing", Severity.ERROR, info.ended,
                         f"task {info.id} {info.name} failed while the aircraft made progress", ev, info.id)

    def _cut_after_loss(self, stamp: float) -> bool:
        """A robot whose ``airborne`` is its motors running (the uQuad) cuts them when it tumbles (its failsafe, error
        706) and says so while it still falls: right when the truth showed a loss of control begun at most
        ``loc_fail_window_s`` before ``stamp`` (whether the robot reported it is invariant 3's other rule)."""
        return any(stamp - self.cfg.loc_fail_window_s <= t <= stamp + SKEW_S + self.cfg.stamp_lag_s
                   for t in self._loc_starts)

    def _confirmed_loss_of_control(self, info: TaskInfo) -> bool:
        """Whether ``info`` failed on a loss of control (the RAL's ``loss of control (...)``, or a module's 604/706)
        that the truth shows too, begun within ``loc_fail_window_s`` before the failure (or ``loc_lead_s`` after
        it): a robot fault (a motor
        lost: the aircraft may well have been closing on its goal the instant before it tumbled). A loss of control
        the truth does not show is not one: that failure is judged by the aircraft's progress as any other (a spin
        the RAL saw on wrongly stamped telemetry, campaign seed 31)."""
        code = reported_error(info.detail)
        said = info.detail.startswith("loss of control") or code in LOSS_OF_CONTROL_CODES
        assert info.ended is not None
        return said and any(info.ended - self.cfg.loc_fail_window_s <= t <= info.ended + self.cfg.loc_lead_s
                            for t in self._loc_starts)

    @property
    def _progress_source(self) -> str:
        return "DSP telemetry" if self.cfg.dsp_commands else "truth"

    def _goal_of(self, info: TaskInfo) -> tuple[float, float, float] | None:
        return self.goal(info) if (info.kind in GOAL_KINDS or info.name in GOAL_KINDS) else None

    # 4. abort within 100 ms
    def _judge_aborts(self, now: float) -> None:
        for task_id in list(self._aborts_due):
            info = self.tasks[task_id]
            r = info.started
            first = next((s.msg for s in self.sent if isinstance(s.msg.command, p.Abort)
                          and s.msg.stamp >= r - SKEW_S), None)
            if first is not None and first.stamp - r - self.cfg.stamp_lag_s <= self.cfg.abort_latency_s:
                self._aborts_due.discard(task_id)
                continue
            if now < r + self.cfg.abort_wait_s:
                continue
            self._aborts_due.discard(task_id)
            self._judged_tasks.add(task_id)
            ev = [f"abort task {info.id} started at {r:.3f} ({info.origin})"]
            if first is not None:
                late = first.stamp - r
                ev.append(f"first Abort sent to the DSP at {first.stamp:.3f} (batch {first.batch_id} of "
                          f"{first.sender!r}): {late * 1000:.0f} ms"
                          + (f" ({self.cfg.stamp_lag_s * 1000:.0f} ms of it the stamps' frame)"
                             if self.cfg.stamp_lag_s else ""))
                self._breach(Invariant.ABORT_LATENCY, "abort_late", Severity.ERROR, r,
                             f"abort reached the DSP after {late * 1000:.0f} ms (limit "
                             f"{self.cfg.abort_latency_s * 1000:.0f} ms)", ev, info.id)
            else:
                ev.append(f"no Abort sent to the DSP within {self.cfg.abort_wait_s:g} s")
                self._breach(Invariant.ABORT_LATENCY, "abort_missing", Severity.CRITICAL, r,
                             "abort never reached the DSP", ev, info.id)

    # 3. the GRI agrees with the truth; a loss of control is reported within 1 s
    def _watch_control(self, now: float, truth: VehicleTruth, prev: VehicleTruth | None, height: float) -> None:
        why = []
        if abs(truth.roll) > self.cfg.loc_attitude_deg or abs(truth.pitch) > self.cfg.loc_attitude_deg:
            why.append(f"attitude roll {truth.roll:.0f} deg, pitch {truth.pitch:.0f} deg "
                       f"(limit {self.cfg.loc_attitude_deg:g})")
        if prev is not None and truth.time_s > prev.time_s:
            turn = (truth.heading - prev.heading + 180.0) % 360.0 - 180.0
            rate = abs(turn) / (truth.time_s - prev.time_s)
            if rate > self.cfg.loc_spin_deg_s:
                why.append(f"heading turning {rate:.0f} deg/s (limit {self.cfg.loc_spin_deg_s:g})")
        if height <= self.cfg.ground_height_m and truth.vel_neu[2] < -self.cfg.loc_impact_m_s:
            why.append(f"ground contact at {-truth.vel_neu[2]:.1f} m/s down")
        if why and self._loc is None:
            self._loc = _Episode(now, evidence=[f"truth at {now:.3f} (sim {truth.time_s:.2f} s): " + "; ".join(why)])
            self._loc_starts.append(now)
            self._loc_ok_since = None
        elif not why and self._loc is not None:
            self._loc_ok_since = self._loc_ok_since if self._loc_ok_since is not None else now
            if now - self._loc_ok_since >= 2.0 and self._loc.reported:
                self._loc = None

    def _judge_loss_of_control(self, now: float) -> None:
        ep = self._loc
        if ep is None or ep.reported:
            return
        lo, hi = ep.since - 0.5, ep.since + self.cfg.loc_report_s
        told = [what for stamp, what in self._reports if lo <= stamp <= hi]
        if told:
            ep.reported = True
            return
        if now < hi + self.cfg.report_wait_s:
            return
        ep.reported = True
        later = [what for stamp, what in self._reports if stamp > hi]
        ev = [*ep.evidence, f"no GRI error or failure event between {lo:.2f} and {hi:.2f}",
              *(["reported later: " + later[0]] if later else ["not reported since"])]
        self._breach(Invariant.GRI_TRUTH, "loss_of_control_unreported", Severity.CRITICAL, ep.since,
                     f"loss of control not reported within {self.cfg.loc_report_s:g} s", ev)

    def _note_report(self, stamp: float, what: str) -> None:
        if any(s == stamp and w == what for s, w in self._reports):
            return
        self._reports.append((stamp, what))
        while len(self._reports) > 500:
            self._reports.popleft()

    # 5. geofence and clearance
    def _envelope(self, now: float, s: _Sample, source: str) -> None:
        cfg = self.cfg
        if cfg.geofence is not None:
            lat0, lon0, radius = cfg.geofence
            d = ground_distance_m(s.lat, s.lon, lat0, lon0)
            ev = [f"{source} at {now:.3f}: {s.lat:.7f}, {s.lon:.7f}", f"{d:.0f} m from the geofence centre "
                  f"{lat0}, {lon0} (radius {radius:g} m)"]
            self._fence = self._episode(self._fence, d > radius, now, cfg.envelope_debounce_s, Invariant.ENVELOPE,
                                        "outside_geofence", Severity.CRITICAL,
                                        f"outside the geofence by {d - radius:.0f} m", ev)
        if cfg.min_clearance_m is not None and s.height is not None:
            climbing = [i for i in self.tasks.values() if (i.kind in CLIMB_KINDS or i.name in CLIMB_KINDS)
                        and i.started - SKEW_S <= now and (i.ended is None or now <= i.ended + cfg.end_grace_s)]
            low = bool(s.airborne) and s.height < cfg.min_clearance_m and not climbing
            ev = [f"{source} at {now:.3f}: {s.height:.1f} m above the take-off point, airborne",
                  f"MIN_CLEARANCE {cfg.min_clearance_m:g} m; no take-off or landing task running",
                  "tasks running: " + (", ".join(f"{i.id} {i.name}" for i in self.tasks.values()
                                                 if i.ended is None) or "none")]
            self._clear = self._episode(self._clear, low, now, cfg.envelope_debounce_s, Invariant.ENVELOPE,
                                        "below_clearance", Severity.CRITICAL,
                                        f"airborne {s.height:.1f} m above the take-off point, below MIN_CLEARANCE "
                                        f"{cfg.min_clearance_m:g} m", ev)

    def _episode(self, ep: _Episode | None, bad: bool, now: float, debounce: float, invariant: Invariant, kind: str,
                 severity: Severity, summary: str, evidence: list[str]) -> _Episode | None:
        """One breach per excursion: reported once it has lasted ``debounce`` seconds; over when it ends."""
        if not bad:
            return None
        if ep is None:
            ep = _Episode(now, evidence=evidence)
        if not ep.reported and now - ep.since >= debounce:
            ep.reported = True
            self._breach(invariant, kind, severity, ep.since, summary,
                         [*ep.evidence, *([f"still at {now:.3f}: " + evidence[-1]] if debounce else [])])
        return ep

    # ------------------------------------------------------------------ history

    def _truth_flowing(self, now: float) -> bool:
        return bool(self.truth) and now - self.truth[-1][0] <= 1.0

    def _truth_airborne(self, t: float) -> bool | None:
        """True/False when the truth was surely in the air/on the ground over the window before ``t`` (and the
        stamp's frame after it)."""
        window = [tr for s, tr in self.truth
                  if t - self.cfg.airborne_window_s <= s <= t + SKEW_S + self.cfg.stamp_lag_s]
        if not window or self.truth[0][0] > t - self.cfg.airborne_window_s:
            return None
        heights = [tr.alt - tr.home[2] for tr in window]
        if min(heights) > self.cfg.airborne_height_m:
            return True
        if max(heights) <= self.cfg.ground_height_m:
            return False
        return None

    def _positions_at(self, t: float) -> list[tuple[_Sample, str]]:
        """Where the aircraft was at stamp ``t``: the truth over the stamp's frame (``t`` to ``t + stamp_lag_s``),
        else the truth sample nearest to it (0.25 s at most), else the nearest DSP telemetry (1 s at most)."""
        out = []
        for s, tr in self.truth:
            if t - SKEW_S <= s <= t + self.cfg.stamp_lag_s + SKEW_S:
                h = tr.alt - tr.home[2]
                out.append((_Sample(s, tr.lat, tr.lon, tr.alt, airborne=h > self.cfg.ground_height_m, height=h),
                            "truth"))
        if out:
            return out
        if self.truth:
            best_truth = min(self.truth, key=lambda x: abs(x[0] - t))
            if abs(best_truth[0] - t) <= 0.25:
                s, tr = best_truth
                h = tr.alt - tr.home[2]
                return [(_Sample(s, tr.lat, tr.lon, tr.alt, airborne=h > self.cfg.ground_height_m, height=h),
                         "truth")]
        best = min(self.telemetry, key=lambda x: abs(x.t - t), default=None)
        if best is not None and abs(best.t - t) <= 1.0:
            return [(best, "DSP telemetry")]
        return []

    def _trim(self, q: deque, now: float, stamp) -> None:  # noqa: ANN001
        while q and now - stamp(q[0]) > self.cfg.history_s:
            q.popleft()
