"""One launched robot for the campaign: a shipped manifest in lockstep at ``--speed max``, a ground station, the
flight-safety monitor as the oracle, and the runner of :mod:`campaign_steps` on it (docs/simulation.md, "Campaign").

The manifest is the shipped one with only the simulation's instruments added: lockstep (``[sim] lockstep =
true``), the .conf's absolute path, and on the DSP simulator's command line its record, its fault-injection
control port and its truth sent to the monitor (on ``uav1_lidar_sim.toml``, whose lidar simulators already take
the truth, through a tee in this process); on ``uquad1_sim.toml`` its simulator's truth stream and control port on
ports chosen here, the monitor connected to the truth (``vehicle=uquad``). Everything started here is stopped by
:meth:`CampaignRobot.close`.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import sys
import threading
import time
import tomllib
from collections import deque
from contextlib import AbstractContextManager, ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec

from bbcs.clock import SimTime
from bbcs.contracts import gri
from bbcs.contracts import tasks as t
from bbcs.geodesy import LocalFrame
from bbcs.lockstep import SimSettings, clock_key, settings_env
from bbcs.session import local_client, open_session
from bbcs.testing import wait_until
from modules.dsp.sim.control import send_command
from ral.gcs.api import Gcs, GcsError, session_config

ROOT = Path(__file__).resolve().parents[2]
for _dir in (Path(__file__).resolve().parent, ROOT / "tests" / "system", ROOT / "tests" / "module_manager"):
    if str(_dir) not in sys.path:
        sys.path.insert(0, str(_dir))
from campaign_steps import Cell, Profile, Step  # noqa: E402
from launch_support import Launch, group_members  # noqa: E402
from monitor_support import MonitorView, attach_monitor, free_udp_port  # noqa: E402

GRID_DEG = 1e-4
END_EVENTS = frozenset({"task_completed", "task_cancelled", "task_replaced", "task_failed", "aborted",
                        "task_rejected"})
STUCK_WALL_S = 90.0
"""Wall seconds without simulated time moving after which the robot is taken as stuck (an incident)."""
LAND_WAIT_SIM_S = 150.0
SETTLE_SIM_S = 4.0
HEALTHY_WALL_S = 60.0
"""Wall seconds the reset waits for every module up: the manager restarts a killed module on the wall clock (its
backoff, at most the manifest's backoff_max_s, then the process's start), however fast the simulation runs."""
"""Simulated seconds watched on the ground after a sequence: the monitor's last judgements are due by then
(commands 3 s, an abort 2 s, a loss of control 3.5 s after the fact)."""


class Stuck(RuntimeError):
    """The simulation stopped moving, or the robot cannot be brought back to the ground: an incident."""


class Tee:
    """Forwards every UDP datagram it gets on 127.0.0.1 to several local ports (the simulator's truth to the
    lidar simulators and the monitor)."""

    def __init__(self, targets: list[int]) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.targets = [("127.0.0.1", p) for p in targets]
        self.stopping = False
        self.thread = threading.Thread(target=self._run, name="campaign-truth-tee", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stopping:
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            for target in self.targets:
                try:
                    self.sock.sendto(data, target)
                except OSError:
                    pass

    def close(self) -> None:
        self.stopping = True
        self.thread.join(2.0)
        self.sock.close()


def _replace_once(text: str, old: str, new: str, what: str) -> str:
    if text.count(old) != 1:
        raise RuntimeError(f"{what}: {old!r} is not in the shipped manifest once (it changed)")
    return text.replace(old, new, 1)


def uquad_campaign_manifest(profile: Profile, workdir: Path, truth: int, control: int) -> Path:
    """The shipped uquad1_sim.toml with the simulation's instruments: lockstep, the .conf's absolute path, the
    loggers writing into the work folder, and the simulator's truth stream and control port on ports chosen here
    (the monitor connects to the truth, the campaign to the control port)."""
    shipped = ROOT / "bbcs_conf" / profile.manifest
    text = shipped.read_text()
    text = _replace_once(text, 'conf = "uquad1.conf"', f'conf = "{shipped.parent / "uquad1.conf"}"', "the .conf")
    if "lockstep = true" not in text:
        text = _replace_once(text, "\n[bus]\n", "\n[sim]\nlockstep = true\n\n[bus]\n", "[bus]")
    text = _replace_once(text, '"--truth", "127.0.0.1:{port:truth}"', f'"--truth", "127.0.0.1:{truth}"',
                         "the simulator's truth stream")
    text = _replace_once(text, '"--control", "127.0.0.1:{port:control}"', f'"--control", "127.0.0.1:{control}"',
                         "the simulator's control port")
    for kind in ("imu_raw", "state", "control"):
        text = _replace_once(text, f'params = {{ kind = "{kind}" }}',
                             f'params = {{ kind = "{kind}", dir = "{workdir / "logs_uquad"}" }}', f"the {kind} logger")
    path = workdir / profile.manifest
    path.write_text(text)
    return path


def free_tcp_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def campaign_manifest(profile: Profile, workdir: Path, monitor_truth: int, control: int) -> tuple[Path, Path,
                                                                                                  Tee | None]:
    """The shipped manifest with the simulation's instruments (module docstring). Returns (manifest, DSP record,
    the truth tee when one is needed)."""
    shipped = ROOT / "bbcs_conf" / profile.manifest
    text = shipped.read_text()
    record = workdir / "dsp_record.jsonl"
    text = _replace_once(text, 'conf = "uav1.conf"', f'conf = "{shipped.parent / "uav1.conf"}"', "the .conf")
    if "lockstep = true" not in text:
        text = _replace_once(text, "\n[bus]\n", "\n[sim]\nlockstep = true\n\n[bus]\n", "[bus]")
    dsp = '"--tcp", "127.0.0.1:{port:dsp}"'
    extra = f', "--record", "{record}", "--control", "127.0.0.1:{control}"'
    tee = None
    if '"--truth-udp", "127.0.0.1:{port:truth}"' in text:  # uav1_lidar_sim.toml: the lidar simulators follow it
        lidar = free_udp_port()
        tee = Tee([lidar, monitor_truth])
        text = _replace_once(text, '"--truth-udp", "127.0.0.1:{port:truth}"', f'"--truth-udp", "127.0.0.1:{tee.port}"',
                             "the DSP simulator's truth")
        text = _replace_once(text, '"--follow-udp", "{port:truth}"', f'"--follow-udp", "{lidar}"',
                             "the lidar simulators' truth")
    else:
        extra += f', "--truth-udp", "127.0.0.1:{monitor_truth}"'
    text = _replace_once(text, dsp + "]", dsp + extra + "]", "the DSP simulator's command line")
    if "params = { ldmrs_host" in text:  # the lidar logger writes its scans into the work folder, not runs/
        text = _replace_once(text, "params = { ldmrs_host", f'params = {{ out_dir = "{workdir / "lidar"}", ldmrs_host',
                             "the lidar logger's params")
    path = workdir / profile.manifest
    path.write_text(text)
    return path, record, tee


UQUAD_GOAL_TOLERANCE_M = 3.0
"""The monitor's goal tolerance on a uQuad (invariant 2): its default of 10 m is the UAV's (the DSP's 11 m grid);
the uQuad's RAL completes a goto within 1 m of its estimate, whose GPS error is well under 2 m."""


def attach_uquad_monitor(router_port: int, workdir: Path, *, robot: str, conf: Path, truth_tcp: int,
                         env: dict[str, str]) -> AbstractContextManager[MonitorView]:
    """The safety monitor on the uQuad's router (:func:`monitor_support.attach_monitor`): no DSP
    (``vehicle=uquad``), the simulator's truth stream on ``truth_tcp``; always stopped, its session closed."""
    return attach_monitor(router_port, workdir, robot=robot, conf=conf, env=env,
                          params={"vehicle": "uquad", "truth_tcp": str(truth_tcp),
                                  "goal_tolerance_m": f"{UQUAD_GOAL_TOLERANCE_M:g}"})


@dataclass
class Outcome:
    """What one step did, as the runner saw it (for the report of a failing sequence)."""

    step: Step
    note: str
    sim_t: float


@dataclass
class Anchor:
    lat: float
    lon: float
    alt: float
    cell_m: float = 0.0
    """0: cells of the DSP's grid; else metres per cell north and east in the local frame at the anchor."""

    def at(self, cell: Cell, height: float | None = None) -> tuple[float, float, float]:
        """A grid cell's coordinates (on the DSP's 10^-4 degree grid, or ``cell_m`` metres a cell in the local frame
        at the anchor), ``height`` metres above the anchor."""
        if self.cell_m:
            lat, lon, _ = LocalFrame(self.lat, self.lon, self.alt).to_geo(cell[1] * self.cell_m,
                                                                            cell[0] * self.cell_m)
            return lat, lon, self.alt + (height or 0.0)
        lat = round(round(self.lat / GRID_DEG) * GRID_DEG + cell[0] * GRID_DEG, 4)
        lon = round(round(self.lon / GRID_DEG) * GRID_DEG + cell[1] * GRID_DEG, 4)
        return lat, lon, self.alt + (height or 0.0)


def task_request(s: Step, a: Anchor) -> gri.TaskRequest:
    """The GRI request of a task step, its places turned into coordinates from the anchor."""
    op = s.op
    simple = {"take_off": lambda: gri.TakeOff(height=s["h"]), "land": gri.Land, "hold": gri.Hold,
              "abort": gri.Abort, "track": gri.Track}
    if op in simple:
        return simple[op]()
    if op in ("goto", "follow_path"):
        wps = [gri.Waypoint(lat=lat, lon=lon, alt=alt) for lat, lon, alt in (a.at(c, s["h"]) for c in s["to"])]
        if op == "goto":
            return gri.Goto(waypoints=wps, speed=s["v"])
        mode = s["mode"]
        return gri.FollowPath(waypoints=wps, speed=s["v"], heading=0.5 if mode == 1 else None,
                              follower="onboard" if mode == 3 else "dsp")
    if op == "survey":
        (n, e), (dn, de) = s["at"][0], s["size"][0]
        corners = [(n, e), (n + dn, e), (n + dn, e + de), (n, e + de)]
        return t.Survey(polygon=[t.Vertex(lat=a.at(c)[0], lon=a.at(c)[1]) for c in corners], height=s["h"],
                        overlap=s["overlap"])
    if op == "orbit":
        lat, lon, _ = a.at(s["at"][0])
        return t.Orbit(lat=lat, lon=lon, radius=s["r"], height=s["h"], turns=s["turns"])
    if op == "pan_tilt":
        return gri.SetPanTilt(pan=s["pan"], tilt=s["tilt"])
    if op == "look_at":
        lat, lon, alt = a.at(s["at"][0])
        return gri.LookAt(lat=lat, lon=lon, alt=alt)
    raise ValueError(f"no request for step {op!r}")


@dataclass
class Sequence:
    steps: list[Step]
    outcomes: list[Outcome] = field(default_factory=list)
    breaches: list[Any] = field(default_factory=list)
    sim_s: float = 0.0
    wall_s: float = 0.0
    incident: str = ""
    watched: dict[str, int] = field(default_factory=dict)
    """What the monitor watched during it (its status counters' increase): an oracle that saw nothing vouches
    for nothing."""
    failed: list[str] = field(default_factory=list)
    """Tasks that failed during it, with the robot's reason (not a breach by itself: the monitor judges that)."""


WATCHED = ("commands_judged", "verdicts", "truth", "gri_compared", "telemetry")


def _counters(monitor: MonitorView) -> dict[str, int]:
    st = monitor.status
    return {k: getattr(st, k) for k in WATCHED} if st is not None else dict.fromkeys(WATCHED, 0)


class CampaignRobot:
    """A robot launched once and flown through many sequences, each ended on the ground by :meth:`reset`."""

    def __init__(self, profile: Profile, workdir: Path, *, log=print, launch_timeout_s: float = 180.0) -> None:
        self.profile = profile
        self.robot = profile.robot
        self.workdir = workdir
        self.log = log
        self.stack = ExitStack()
        self.lock = threading.Lock()
        self.events: list[gri.GriEvent] = []
        self._event_keys: set[tuple[float, str, int, str]] = set()
        self.state: gri.GriState | None = None
        self.sim_t = 0.0
        self._sim_seen = time.monotonic()
        self.link: Gcs | None = None
        self.lost_motors: set[int] = set()
        """uQuad motors a ``motor_loss`` took, repaired by the reset."""
        self.killed: dict[str, int] = {}
        """Module → pid killed and not yet seen replaced by a new process that is up."""
        self._kills: dict[str, deque[float]] = {}
        """Module → wall times of its kills (the manager's restart intensity counts restarts on the wall)."""
        try:
            self._start(launch_timeout_s)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ start and stop

    def _start(self, timeout_s: float) -> None:
        workdir = self.workdir
        workdir.mkdir(parents=True, exist_ok=True)
        uquad = self.profile.manifest.startswith("uquad")
        tee = None
        if uquad:  # the simulator's truth stream is TCP (a server the monitor connects to), so is its control port
            truth, self.control = free_tcp_port(), free_tcp_port()
            manifest, self.record = uquad_campaign_manifest(self.profile, workdir, truth, self.control), None
        else:
            truth, self.control = free_udp_port(), free_udp_port()
            manifest, self.record, tee = campaign_manifest(self.profile, workdir, truth, self.control)
        sup = tomllib.loads(manifest.read_text()).get("supervision", {})
        self.intensity, self.period_s = int(sup.get("intensity", 5)), float(sup.get("period_s", 10.0))
        if tee is not None:
            self.stack.callback(tee.close)
        t0 = time.monotonic()
        self.launch = Launch(manifest, workdir, "--speed", "max")
        self.stack.callback(self._stop_launch)
        self.launch.wait_line("modules up", timeout_s)
        self.launch_s = time.monotonic() - t0
        endpoint = f"tcp/127.0.0.1:{self.launch.port}"
        self.session = open_session(local_client(self.launch.port))
        self.stack.callback(self.session.close)
        decode = msgspec.msgpack.Decoder(SimTime).decode
        sub = self.session.declare_subscriber(clock_key(self.robot),
                                              lambda s: self._on_time(decode(s.payload.to_bytes())))
        self.stack.callback(sub.undeclare)
        self.gcs = Gcs(session_config([endpoint]), name="campaign", timeout_s=20.0)
        self.stack.callback(self.gcs.close)
        self.gcs.watch(self.robot, self._on_state)
        self.gcs.events(self.robot, self._on_event)
        self._open_link()
        self.stack.callback(self._close_link)
        # a lockstep member: the simulation steps only once the monitor has judged what the last step produced
        # (an outside observer falls behind a simulation at --speed max on a loaded machine)
        sim = SimSettings(robot=self.robot, connect=[endpoint], speed="max")
        if uquad:
            self.monitor = self.stack.enter_context(attach_uquad_monitor(
                self.launch.port, workdir, robot=self.robot, conf=ROOT / "bbcs_conf" / "uquad1.conf", truth_tcp=truth,
                env=settings_env(sim)))
        else:
            self.monitor = self.stack.enter_context(
                attach_monitor(self.launch.port, workdir, truth_port=truth, env=settings_env(sim)))
        # the uQuad's GRI has no home before its first take-off: its anchor is where it stands at the start
        first = self._wait(lambda: self.state is not None and (self.state.home is not None or uquad)
                           and self.state.position is not None and self.state.link == "up", 60.0,
                           "a GRI state with home, position and the campaign's link")
        origin = first.home or first.position
        assert origin is not None
        self.anchor = Anchor(origin.lat, origin.lon, origin.alt, self.profile.cell_m)
        if uquad:  # no DSP telemetry on a uQuad: the book, the GRI and the simulator's truth
            wait_until(lambda: self._uquad_watched(), 60.0, "the safety monitor watching the uQuad")
        else:
            self.monitor.wait_watching(60.0)
        self.ready_s = time.monotonic() - t0

    monitor: MonitorView

    def _uquad_watched(self) -> bool:
        st = self.monitor.status
        if self.monitor.proc.poll() is not None:
            raise AssertionError(f"the monitor exited {self.monitor.proc.returncode}: "
                                 f"{self.monitor.log.read_text()[-2000:]}")
        return st is not None and st.books > 0 and st.gri_states > 0 and st.truth > 0

    def _stop_launch(self) -> None:
        try:
            self.launch.stop(timeout_s=20.0)
        finally:
            self.launch.cleanup()
            (self.workdir / "launch.out").write_text("\n".join(self.launch.lines) + "\n")

    def close(self) -> None:
        self.stack.close()

    def _open_link(self) -> None:
        self.link = Gcs(session_config([f"tcp/127.0.0.1:{self.launch.port}"]), name="campaign_link", link=[self.robot])

    def _close_link(self) -> None:
        if self.link is not None:
            self.link.close()
            self.link = None

    # ------------------------------------------------------------------ what the robot says

    def _on_time(self, now: SimTime) -> None:
        if now.t > self.sim_t:
            self.sim_t = now.t
            self._sim_seen = time.monotonic()

    def _on_state(self, state: gri.GriState) -> None:
        with self.lock:
            self.state = state

    def _on_event(self, event: gri.GriEvent) -> None:
        key = (event.stamp, event.kind, event.task_id, event.detail)
        with self.lock:
            if key not in self._event_keys:  # a restarted RAL replays its last events
                self._event_keys.add(key)
                self.events.append(event)

    def _wait(self, pred, sim_s: float, what: str, *, wall_s: float | None = None) -> gri.GriState:  # noqa: ANN001
        """Until ``pred()`` holds, at most ``sim_s`` simulated seconds (``wall_s``: wall seconds instead, for what
        the robot does on the wall clock); Stuck when simulated time stops moving."""
        end = self.sim_t + sim_s
        wall_end = None if wall_s is None else time.monotonic() + wall_s
        while True:
            with self.lock:
                state = self.state
            if pred():
                assert state is not None or self.state is not None
                return self.state  # type: ignore[return-value]
            if wall_end is None and self.sim_t >= end:
                raise Stuck(f"{what}: not within {sim_s:g} simulated seconds")
            if wall_end is not None and time.monotonic() >= wall_end:
                raise Stuck(f"{what}: not within {wall_s:g} wall seconds")
            if time.monotonic() - self._sim_seen > STUCK_WALL_S:
                raise Stuck(f"{what}: simulated time stopped at {self.sim_t:.1f} s for {STUCK_WALL_S:g} wall s")
            if self.launch.proc.poll() is not None:
                raise Stuck(f"{what}: cromat launch exited {self.launch.proc.returncode}")
            time.sleep(0.02)

    def sleep_sim(self, s: float) -> None:
        end = self.sim_t + s
        self._wait(lambda: self.sim_t >= end, s + 1.0, f"{s:g} simulated seconds")

    # ------------------------------------------------------------------ steps

    def run(self, seq: Sequence) -> Sequence:
        """Fly ``seq.steps``, then :meth:`reset`; the monitor's breaches of that span and what each step did go
        into ``seq``. An incident (the robot stuck, not back on the ground) ends it early and is recorded."""
        mark = len(self.monitor.seen())
        first_event = len(self.events)
        before = _counters(self.monitor)
        sim0, wall0 = self.sim_t, time.monotonic()
        self.last_task = 0
        try:
            for s in seq.steps:
                try:
                    note = self.do(s)
                except GcsError as exc:  # a request no one answered (the RAL restarting): an answer of its own
                    note = f"no answer: {exc}"
                seq.outcomes.append(Outcome(s, note, self.sim_t))
            self.reset()
        except Stuck as exc:
            seq.incident = str(exc)
        except GcsError as exc:
            seq.incident = f"the ground station, resetting: {exc}"
        seq.sim_s, seq.wall_s = self.sim_t - sim0, time.monotonic() - wall0
        seq.breaches = self.monitor.seen()[mark:]
        seq.watched = {k: v - before[k] for k, v in _counters(self.monitor).items()}
        with self.lock:
            seq.failed = [f"task {e.task_id}: {e.detail}" for e in self.events[first_event:] if e.kind == "task_failed"]
        return seq

    def do(self, s: Step) -> str:
        """One step; returns what came of it (a refusal is an answer, not an incident)."""
        op = s.op
        if op == "wait":
            self.sleep_sim(s["s"])
            return "waited"
        if op == "done":
            return self._until_done(s["s"])
        if op == "kill":
            return self._kill(s["module"])
        if op == "link_loss":
            self._close_link()
            time.sleep(s["s"])  # the link's timeouts are on the wall clock (docs/simulation.md)
            self._open_link()
            return f"link cut {s['s']:g} wall s"
        if op == "bad_frame":
            return send_command("127.0.0.1", self.control, f"spoil {s['field']}={s['value']} {s['count']}")
        if op == "motor_loss":
            answer = self._motor(s["motor"], 0.0)
            if answer.get("ok"):
                self.lost_motors.add(s["motor"])
            return f"motor {s['motor']} lost: {answer}"
        if op == "restart_ral":
            state = self.state
            ral = next((m for m in (state.modules if state else []) if m.name == "ral"), None)
            reply = self.gcs.restart(self.robot, "ral")
            if reply.accepted and ral is not None and ral.pid is not None:
                # the reset waits for a new RAL process: a state published before the restart still shows the old
                # one up, and a `land` sent to it then got no answer (seed 7, sequence 136's incident)
                self.killed["ral"] = ral.pid
            return self._reply(reply)
        if op == "route":
            routes = self.gcs.route(self.robot, "pan_tilt", "datos", s["datos"])
            return f"pan_tilt.datos = {routes.routes.get('pan_tilt', {}).get('datos')}"
        return self._reply(self.gcs.send(self.robot, task_request(s, self.anchor)))

    def _motor(self, motor: int, efficiency: float) -> dict[str, Any]:
        """The uQuad simulator's control port: that motor's thrust efficiency from the next physics step on."""
        with socket.create_connection(("127.0.0.1", self.control), timeout=10.0) as sock:
            sock.sendall(json.dumps({"motor": motor, "efficiency": efficiency}).encode() + b"\n")
            return json.loads(sock.makefile("rb").readline())

    def _reply(self, reply: gri.TaskReply) -> str:
        if reply.accepted:
            self.last_task = reply.task_id
            return f"accepted task {reply.task_id}"
        return f"refused: {reply.reason}"

    def _until_done(self, sim_s: float) -> str:
        task = self.last_task
        if not task:
            return "no task to wait for"
        found: list[gri.GriEvent] = []

        def ended() -> bool:
            with self.lock:
                found[:] = [e for e in self.events if e.task_id == task and e.kind in END_EVENTS]
            return bool(found)

        try:
            self._wait(ended, sim_s, f"task {task} ending")
        except Stuck:
            if self.sim_t < 1.0 or time.monotonic() - self._sim_seen > STUCK_WALL_S:
                raise
            return f"task {task} still running after {sim_s:g} s"
        e = found[0]
        return f"task {task} {e.kind}" + (f": {e.detail}" if e.detail else "")

    def _kill(self, module: str) -> str:
        state = self.state
        status = next((m for m in (state.modules if state else []) if m.name == module), None)
        if status is None or status.pid is None:
            return f"{module} has no process now"
        if status.pid not in group_members(self.launch.pgid):  # only a process of this launch, ever
            return f"{module}'s pid {status.pid} is not (or no longer) of this launch"
        # the manager gives a module up after `intensity` restarts in `period_s` wall seconds (rightly: a crash
        # loop); a campaign killing faster than that tests its own kill rate, so it leaves one restart spare
        now = time.monotonic()
        kills = self._kills.setdefault(module, deque())
        while kills and kills[0] <= now - self.period_s:
            kills.popleft()
        if len(kills) >= self.intensity - 2:
            return (f"{module} not killed: killed {len(kills)} times in the last {self.period_s:g} wall s (the "
                    f"manager's restart intensity is {self.intensity})")
        try:
            os.kill(status.pid, signal.SIGKILL)
        except ProcessLookupError:
            return f"{module} (pid {status.pid}) already gone"
        kills.append(now)
        self.killed[module] = status.pid
        return f"killed {module} (pid {status.pid})"

    # ------------------------------------------------------------------ between sequences

    def reset(self) -> None:
        """Back to the start of a sequence: linked, routes as the manifest has them, every module up, on the
        ground, and the monitor's last judgements made."""
        if self.link is None:
            self._open_link()
        for motor in sorted(self.lost_motors):  # repaired (the aircraft is on the ground by now: its failsafe)
            answer = self._motor(motor, 1.0)
            if not answer.get("ok"):
                raise Stuck(f"motor {motor} not repaired: {answer}")
        self.lost_motors.clear()
        self.wait_healthy()
        if self.profile.routes:
            routes = self.gcs.routes(self.robot).routes.get("pan_tilt", {})
            if routes.get("datos") != self.profile.routes[0]:
                self.gcs.route(self.robot, "pan_tilt", "datos", self.profile.routes[0])
        tried: list[str] = []
        for _ in range(3):
            if self._on_ground():
                break
            reply = self.gcs.send(self.robot, gri.Land())
            if not reply.accepted:
                tried.append(f"land refused at t={self.sim_t:.1f}: {reply.reason}")
                self.wait_healthy()  # a module it needs may have gone down since (a restart is on the wall clock)
                self.sleep_sim(2.0)
                continue
            self.last_task = reply.task_id
            tried.append(self._until_done(LAND_WAIT_SIM_S) + f" at t={self.sim_t:.1f}")
            try:
                self._wait(self._on_ground, 20.0, "on the ground")
            except Stuck:
                if time.monotonic() - self._sim_seen > STUCK_WALL_S:
                    raise
        if not self._on_ground():
            st = self.state
            raise Stuck("not back on the ground after three landings (" + "; ".join(tried) + "; GRI airborne="
                        + f"{st.airborne if st else None}, errors {[e.name for e in st.errors[-3:]] if st else []})")
        self.sleep_sim(SETTLE_SIM_S)
        try:
            self.monitor.settle(60.0)
        except AssertionError as exc:
            raise Stuck(f"the monitor did not judge every command: {str(exc).splitlines()[0]}") from None

    def recovered(self) -> bool:
        """After an incident: whether a reset now succeeds (else the robot is relaunched)."""
        if self.launch.proc.poll() is not None:
            return False
        try:
            self.reset()
        except (Stuck, GcsError) as exc:
            self.log(f"  the robot did not recover: {exc}")
            return False
        return True

    def wait_healthy(self, wall_s: float = HEALTHY_WALL_S) -> None:
        """Until a GRI state newer than now (the RAL alive) shows every module up, each one killed as a new
        process (a state published before the manager saw the kill still shows the old one up), the manager up and
        our link. On the wall clock: the manager restarts modules on it."""
        with self.lock:
            since = self.state.stamp if self.state is not None else 0.0

        def healthy() -> bool:
            st = self.state
            if st is None or st.stamp <= since or not st.manager_up or st.link != "up" \
                    or not all(m.state == "up" for m in st.modules):
                return False
            pids = {m.name: m.pid for m in st.modules}
            return all(pids.get(name) not in (None, pid) for name, pid in self.killed.items())

        self._wait(healthy, 0.0, "every module up (a killed one as a new process), a fresh GRI state and the "
                   "campaign's link", wall_s=wall_s)
        self.killed.clear()

    def _on_ground(self) -> bool:
        st = self.state
        return st is not None and st.airborne is False
