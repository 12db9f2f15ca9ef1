"""The randomized mission campaign's vocabulary (docs/simulation.md, "Campaign"): steps, their text form, and the
seeded generator of sequences. Pure: no robot, no clock.

A **step** is one thing a ground station or the world does to the robot: a task (``take_off``, ``goto``,
``follow_path`` in path mode 0, 1 or 3, ``survey``, ``orbit``, ``land``, ``hold``, ``abort``, ``pan_tilt``,
``look_at``, ``track``), a route swap (``route``), a fault (``kill`` -9 of a module, ``link_loss``, a bad telemetry
frame ``bad_frame``, ``restart_ral``, ``motor_loss`` on the uQuad) or time passing (``wait`` simulated seconds,
``done``: until the last task ends). Its text is ``op key=value ...``; a sequence is its steps joined by ``; ``,
so a failing one is printed as a command line that runs it again (``python bench/campaign.py --robot uav
--steps "take_off; done s=60"``).

Places are grid cells of the DSP protocol's 10^-4 degrees (``north:east``) from the robot's **anchor** (where the
simulator put it at launch), heights in metres above the anchor: the runner turns them into coordinates, so a
sequence means the same flight on every launch, wherever earlier sequences left the aircraft. On the uQuad (a
small quadrotor, :attr:`Profile.cell_m`) a cell is 2 metres of its local frame instead.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

Cell = tuple[int, int]
"""Grid cells north and east of the anchor."""


def _path(text: str) -> tuple[Cell, ...]:
    cells = []
    for part in text.split("/"):
        north, sep, east = part.partition(":")
        if not sep:
            raise ValueError(f"{part!r} is not NORTH:EAST grid cells")
        cells.append((int(north), int(east)))
    return tuple(cells)


def _show_path(cells: tuple[Cell, ...]) -> str:
    return "/".join(f"{n}:{e}" for n, e in cells)


def _word(text: str) -> str:
    if not text or any(c in text for c in " ;="):
        raise ValueError(f"{text!r} is not a single word")
    return text


def _num(value: float) -> str:
    return f"{value:g}"


@dataclass(frozen=True)
class Arg:
    parse: Callable[[str], Any]
    show: Callable[[Any], str] = str
    default: Any = None


PATH = Arg(_path, _show_path)
ARGS: dict[str, dict[str, Arg]] = {
    "take_off": {"h": Arg(float, _num, default=10.0)},
    "land": {},
    "hold": {},
    "abort": {},
    "goto": {"to": PATH, "h": Arg(float, _num, default=15.0), "v": Arg(float, _num, default=5.0)},
    "follow_path": {"mode": Arg(int, default=0), "to": PATH, "h": Arg(float, _num, default=15.0),
                    "v": Arg(float, _num, default=5.0)},
    "survey": {"at": PATH, "size": PATH, "h": Arg(float, _num, default=25.0), "overlap": Arg(float, _num, default=0.3)},
    "orbit": {"at": PATH, "r": Arg(float, _num, default=25.0), "h": Arg(float, _num, default=20.0),
              "turns": Arg(float, _num, default=0.5)},
    "pan_tilt": {"pan": Arg(float, _num, default=0.0), "tilt": Arg(float, _num, default=-20.0)},
    "look_at": {"at": PATH},
    "track": {},
    "route": {"datos": Arg(int)},
    "kill": {"module": Arg(_word)},
    "link_loss": {"s": Arg(float, _num, default=3.0)},
    "bad_frame": {"field": Arg(_word), "value": Arg(_word), "count": Arg(int, default=1)},
    "restart_ral": {},
    "motor_loss": {"motor": Arg(int)},
    "wait": {"s": Arg(float, _num, default=5.0)},
    "done": {"s": Arg(float, _num, default=60.0)},
}
"""Every step: its arguments, how each is read and written, the default when left out (None: required)."""
TASKS = frozenset({"take_off", "land", "hold", "abort", "goto", "follow_path", "survey", "orbit", "pan_tilt",
                   "look_at", "track"})
FAULTS = frozenset({"kill", "link_loss", "bad_frame", "restart_ral", "motor_loss"})
FOLLOW_MODES = (0, 1, 3)
"""follow_path's path modes: 0 the DSP's follower, 1 with a heading, 3 the path follower module's onboard one."""


@dataclass(frozen=True)
class Step:
    op: str
    args: tuple[tuple[str, Any], ...] = ()

    def __getitem__(self, key: str) -> Any:
        for k, v in self.args:
            if k == key:
                return v
        return ARGS[self.op][key].default

    def __str__(self) -> str:
        spec = ARGS[self.op]
        return " ".join([self.op, *(f"{k}={spec[k].show(v)}" for k, v in self.args)])


def step(op: str, **args: Any) -> Step:
    """A step, its arguments checked against :data:`ARGS` (and put in its order)."""
    if op not in ARGS:
        raise ValueError(f"unknown step {op!r} (one of {', '.join(ARGS)})")
    spec = ARGS[op]
    unknown = sorted(set(args) - set(spec))
    if unknown:
        raise ValueError(f"step {op!r} takes no {', '.join(unknown)} (it takes {', '.join(spec) or 'nothing'})")
    missing = [k for k, a in spec.items() if a.default is None and k not in args]
    if missing:
        raise ValueError(f"step {op!r} needs {', '.join(missing)}")
    return Step(op, tuple((k, args[k]) for k in spec if k in args))


def parse_step(text: str) -> Step:
    """``op key=value ...`` → a Step; ValueError says what is wrong."""
    words = text.split()
    if not words:
        raise ValueError("an empty step")
    op, rest = words[0], words[1:]
    if op not in ARGS:
        raise ValueError(f"unknown step {op!r} (one of {', '.join(ARGS)})")
    args: dict[str, Any] = {}
    for word in rest:
        key, sep, value = word.partition("=")
        if not sep or key not in ARGS[op]:
            raise ValueError(f"step {op!r}: {word!r} is not one of {', '.join(f'{k}=' for k in ARGS[op]) or 'none'}")
        try:
            args[key] = ARGS[op][key].parse(value)
        except ValueError as exc:
            raise ValueError(f"step {op!r}: {key}={value!r}: {exc}") from None
    return step(op, **args)


def parse_steps(text: str) -> list[Step]:
    """A sequence as printed (steps joined by ``;``)."""
    return [parse_step(part) for part in text.split(";") if part.strip()]


def show_steps(steps: Sequence[Step]) -> str:
    return "; ".join(str(s) for s in steps)


# ---------------------------------------------------------------- robots


@dataclass(frozen=True)
class Profile:
    """One robot the campaign flies: its shipped manifest and what it offers."""

    name: str
    manifest: str
    """A file of bbcs_conf/."""
    tasks: frozenset[str]
    killable: tuple[str, ...]
    """Modules a ``kill`` may hit: those the manager restarts (a ``restart = "never"`` module stays dead)."""
    routes: tuple[int, ...] = ()
    """Slots ``route`` may put on the pan & tilt's DATOS (its manifest default first)."""
    bad_fields: tuple[tuple[str, str], ...] = ()
    """Telemetry fields and values a ``bad_frame`` may spoil (the DSP simulator's control port)."""
    robot: str = "uav1"
    """The robot's name in its manifest."""
    cell_m: float = 0.0
    """0: places are cells of the DSP's 10^-4 degree grid (about 11 m); else metres of the robot's local
    east-north-up frame per cell (the uQuad, a small quadrotor: its tests fly within about 12 m of home)."""
    heights: tuple[float, ...] = (10.0, 15.0, 20.0, 25.0)
    speeds: tuple[float, ...] = (3.0, 5.0, 8.0)
    take_off_h: float | None = None
    """The take-off height the generator asks (None: the step's default, 10 m)."""
    follow_modes: tuple[int, ...] = (0,)
    motors: int = 0
    """Motors a ``motor_loss`` may take (the uQuad simulator's control port: that motor gives no thrust until the
    reset repairs it); 0: none."""

    @property
    def faults(self) -> frozenset[str]:
        """The faults the generator gives this robot (a bad telemetry frame needs the DSP simulator)."""
        return FAULTS - ({"bad_frame"} if not self.bad_fields else set()) \
            - ({"motor_loss"} if not self.motors else set())


DSP_BAD_FIELDS = (("position.lat", "200"), ("heading", "180"), ("attitude.roll", "nan"), ("status.mode", "9"),
                  ("status.queue_length", "600"), ("status.reserved_flags", "8"))
PROFILES: dict[str, Profile] = {
    "uav": Profile(
        "uav", "uav1_sim.toml",
        tasks=frozenset({"take_off", "land", "hold", "abort", "goto", "follow_path", "pan_tilt", "look_at",
                         "track"}),
        killable=("dsp", "telemetry", "pan_tilt", "path_follower", "vision", "ral"),
        routes=(10, 20), bad_fields=(*DSP_BAD_FIELDS, ("pan_tilt.mode", "5")), follow_modes=FOLLOW_MODES),
    "survey": Profile(
        "survey", "uav1_lidar_sim.toml",
        tasks=frozenset({"take_off", "land", "hold", "abort", "goto", "follow_path", "survey", "orbit"}),
        killable=("dsp", "telemetry", "path_follower", "trajectory", "ral"),
        bad_fields=DSP_BAD_FIELDS),
    "uquad": Profile(
        "uquad", "uquad1_sim.toml",
        tasks=frozenset({"take_off", "land", "hold", "abort", "goto", "follow_path"}),
        # the flight module is restart = "never" (a restarted flight loop would recalibrate in the air), and the
        # simulator and the motor driver are processes, not modules: the loggers and the RAL are restarted
        killable=("log_imu_raw", "log_state", "log_control", "ral"),
        robot="uquad1", cell_m=2.0, heights=(2.0, 3.0, 4.0, 5.0), speeds=(1.0, 2.0, 3.0), take_off_h=3.0,
        motors=4),
}
"""The robots in lockstep: the DSP's UAV in two manifests and the uQuad (its simulator the stepper,
docs/uquad.md §1.1)."""


# ---------------------------------------------------------------- the generator

AREA = 4
"""Places lie within this many cells of the anchor (about 45 m on the DSP's grid, 8 m on the uQuad's): the
aircraft never wanders off."""


@dataclass(frozen=True)
class GenConfig:
    min_actions: int = 2
    max_actions: int = 5
    fault_p: float = 0.2
    """Chance an action is a fault."""
    complete_p: float = 0.6
    """Chance a task is waited for to its end (else a few seconds, then the next step interrupts it)."""
    long_link_loss_p: float = 0.2
    """Chance a link loss lasts past the failsafe timeout (12 wall seconds instead of 3)."""


def sequence_rng(seed: int, index: int) -> random.Random:
    """Sequence ``index`` of campaign ``seed`` draws from its own generator: any one is made again alone."""
    return random.Random(f"cromat-campaign:{seed}:{index}")


def _cell(rng: random.Random) -> Cell:
    return (rng.randint(-AREA, AREA), rng.randint(-AREA, AREA))


def _route(rng: random.Random, n: int) -> tuple[Cell, ...]:
    cells: list[Cell] = []
    while len(cells) < n:
        c = _cell(rng)
        if not cells or c != cells[-1]:
            cells.append(c)
    return tuple(cells)


def _task(rng: random.Random, op: str, profile: Profile) -> Step:
    """A task the robot admits: the survey's lines wide enough for the generator's turns (uav1_lidar_sim.toml:
    at 25 m or more with 20 % overlap or less), heights above MIN_CLEARANCE, speeds within MAX_SPEED."""
    h = rng.choice(profile.heights)
    if op == "take_off":
        return step(op) if profile.take_off_h is None else step(op, h=profile.take_off_h)
    if op == "goto":
        return step(op, to=_route(rng, rng.randint(1, 3)), h=h, v=rng.choice(profile.speeds))
    if op == "follow_path":
        return step(op, mode=rng.choice(profile.follow_modes), to=_route(rng, rng.randint(2, 4)), h=h,
                    v=rng.choice(profile.speeds))
    if op == "survey":
        return step(op, at=(_cell(rng),), size=((rng.randint(2, 4), rng.randint(2, 4)),),
                    h=rng.choice((25.0, 30.0)), overlap=rng.choice((0.0, 0.1, 0.2)))
    if op == "orbit":
        return step(op, at=(_cell(rng),), r=float(rng.choice((15, 25, 40))), h=rng.choice((15.0, 20.0, 25.0)),
                    turns=rng.choice((0.25, 0.5, 1.0)))
    if op == "pan_tilt":
        return step(op, pan=float(rng.randrange(-170, 171, 10)), tilt=float(rng.randrange(-80, 1, 10)))
    if op == "look_at":
        return step(op, at=(_cell(rng),))
    return step(op)


def _fault(rng: random.Random, profile: Profile, cfg: GenConfig) -> Step:
    kinds = ["kill", "link_loss", "restart_ral"] + (["bad_frame"] * 2 if profile.bad_fields else []) \
        + (["motor_loss"] if profile.motors else [])
    kind = rng.choice(kinds)
    if kind == "motor_loss":
        return step(kind, motor=rng.randrange(profile.motors))
    if kind == "kill":
        return step(kind, module=rng.choice(profile.killable))
    if kind == "link_loss":
        return step(kind, s=12.0 if rng.random() < cfg.long_link_loss_p else 3.0)
    if kind == "bad_frame":
        field, value = rng.choice(profile.bad_fields)
        return step(kind, field=field, value=value, count=rng.choice((1, 1, 2)))
    return step(kind)


ENDS_AT_GOAL = frozenset({"take_off", "land", "goto", "follow_path", "survey", "orbit"})
"""Tasks that complete by themselves; the others (hold, pan & tilt, tracking) run until replaced."""
AIRBORNE_WEIGHTS = {"goto": 4, "follow_path": 3, "survey": 2, "orbit": 2, "hold": 1, "abort": 1, "land": 1,
                    "pan_tilt": 1, "look_at": 1, "track": 1, "route": 1}


def generate(seed: int, index: int, profile: Profile, cfg: GenConfig = GenConfig()) -> list[Step]:
    """Sequence ``index`` of campaign ``seed`` on ``profile``: it starts on the ground (the runner's reset), takes off
    most of the time, then flies tasks, swaps and faults, each task waited for to its end or interrupted."""
    rng = sequence_rng(seed, index)
    out: list[Step] = []
    airborne = False
    for _ in range(rng.randint(cfg.min_actions, cfg.max_actions)):
        if rng.random() < cfg.fault_p:
            out.append(_fault(rng, profile, cfg))
            continue
        if not airborne:
            op = "take_off" if rng.random() < 0.85 else rng.choice(sorted(profile.tasks - {"take_off"}))
        else:
            choices = [(op, w) for op, w in AIRBORNE_WEIGHTS.items()
                       if op in profile.tasks or (op == "route" and profile.routes)]
            op = rng.choices([c for c, _ in choices], [w for _, w in choices])[0]
        if op == "route":
            out.append(step("route", datos=rng.choice(profile.routes)))
            out.append(step("wait", s=float(rng.choice((2, 5)))))
            continue
        out.append(_task(rng, op, profile))
        if op in ("take_off", "land") or (op in ENDS_AT_GOAL and rng.random() < cfg.complete_p):
            out.append(step("done", s=90.0))
        else:
            out.append(step("wait", s=float(rng.choice((2, 5, 10)))))
        if op == "take_off":
            airborne = True
        elif op == "land":
            airborne = False
    return out
