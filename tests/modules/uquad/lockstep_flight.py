"""What the uQuad's system tests share: the shipped uquad1_sim.toml in lockstep (``[sim] lockstep = true``,
launched with ``--speed max``: the simulator steps on the bus barrier, every bus process reads simulated time,
docs/uquad.md §1.1) and the simulator's truth stream, read with deadlines in simulated seconds."""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from modules.uquad.sim.truth_stream import TruthStream

ROOT = Path(__file__).resolve().parents[3]
MANIFEST = ROOT / "bbcs_conf" / "uquad1_sim.toml"
SPEED = ("--speed", "max")
"""``cromat launch`` arguments: as fast as every member allows."""
WALL_GUARD = 10.0
"""A wait in simulated seconds gives up after this many times as long on the wall (a minute at least): only a
simulator that stopped stepping reaches it."""


def lockstep_manifest(tmp_path: Path, edit: Callable[[str], str] | None = None) -> Path:
    """The shipped uquad1_sim.toml with its shipped .conf (its flight processes at nice -10), the loggers writing
    into ``tmp_path``, in lockstep; ``edit`` changes the text further."""
    text = MANIFEST.read_text().replace('conf = "uquad1.conf"', f'conf = "{MANIFEST.parent / "uquad1.conf"}"')
    for kind in ("imu_raw", "control", "state"):
        old = f'params = {{ kind = "{kind}" }}'
        assert old in text, f"the {kind} logger's params in uquad1_sim.toml changed"
        text = text.replace(old, f'params = {{ kind = "{kind}", dir = "{tmp_path}" }}')
    assert "[sim]" not in text and "\n[bus]\n" in text, "uquad1_sim.toml: no [bus] table to put [sim] before"
    text = text.replace("\n[bus]\n", "\n[sim]\nlockstep = true\n\n[bus]\n", 1)
    if edit is not None:
        text = edit(text)
    path = tmp_path / "uquad1_sim.toml"
    path.write_text(text)
    return path


def sim_ports(log_dir: Path) -> dict[str, int]:
    """The simulator's ports from its readiness line (its log)."""
    text = (log_dir / "uquad_sim.log").read_text()
    return {name: int(port) for name, port in re.findall(r"(\w+)=tcp://127.0.0.1:(\d+)", text)}


class Truth(TruthStream):
    """The simulator's truth stream (JSON lines of the true state). In lockstep each line carries ``t`` (simulated
    seconds since the start) and ``stamp`` (the same instant as the robot's clocks read it: GRI and error stamps)."""

    @property
    def epoch(self) -> float:
        """Wall time of simulated 0: a stamp minus its ``t``."""
        return self.last["stamp"] - self.last["t"]

    def settled(self, window_s: float, metres: float) -> bool:
        """Whether the quad stayed within ``metres`` of where it is now over the last ``window_s`` simulated s."""
        lines = self.lines
        end = lines[-1]["t"]
        if lines[0]["t"] > end - window_s:
            return False
        here = np.array(lines[-1]["x"][:3])
        for line in reversed(lines):
            if line["t"] < end - window_s:
                return True
            if np.linalg.norm(np.array(line["x"][:3]) - here) >= metres:
                return False
        return True

    def wait(self, predicate: Callable[[], object], sim_s: float, what: str) -> None:
        """Poll ``predicate`` with a deadline in simulated seconds (the flight is the same at any load, only slower
        or faster on the wall); a wall guard ends the wait if the simulator stops."""
        wall_end = time.monotonic() + max(60.0, WALL_GUARD * sim_s)
        while not self.lines:
            if time.monotonic() > wall_end:
                raise AssertionError(f"no truth from the simulator: {what}")
            time.sleep(0.01)
        start = self.last["t"]
        while not predicate():
            if self.last["t"] - start > sim_s or time.monotonic() > wall_end:
                raise AssertionError(f"not within {sim_s:g} simulated s ({self.last['t'] - start:.1f} s passed, "
                                     f"the wall guard {'passed' if time.monotonic() > wall_end else 'not passed'}): "
                                     f"{what}")
            time.sleep(0.01)

    def close(self) -> None:
        self.sock.close()
