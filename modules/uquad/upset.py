"""The uQuad's own reflex to a loss of control: cut the motors when its estimate shows it tumbling. Pure.

Seed 002 asks the flight to stop on any driver error, and its motors stop when commands stop; a quadrotor whose
estimate shows it tilted beyond ``CUT_TILT_DEG`` (roll and pitch together: the angle of its up axis from the
vertical) for ``CUT_TILT_S`` has lost its attitude — a motor or propeller lost, a starved loop — and no landing
can be flown without attitude: motors running only drive it, tumbling, into the ground or along it upside down.
So the flight loop stops them at once, as a ``cut`` driver error does, without waiting for the bus; the RAL is
told by error 706 and by the telemetry (ral/health.py), and its landing then finds the quadrotor on the ground.

After the cut the planner is idle, but the quadrotor is still falling: :class:`FallWatch` keeps it reported
airborne (and error 706 in its telemetry) until its IMU shows it at rest, so no landing is judged completed in
mid-air (the campaign found one: a motor lost 3 m up during a landing, reported landed while falling).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


def tilt_deg(roll_rad: float, pitch_rad: float) -> float:
    """Angle between the body's up axis and the vertical, degrees (0 level, 180 upside down)."""
    c = math.cos(roll_rad) * math.cos(pitch_rad)
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


@dataclass
class TumbleCut:
    max_tilt_deg: float = 70.0
    hold_s: float = 0.1
    _since: float | None = None
    reason: str = ""
    """Why the last cut was decided."""

    def update(self, now: float, roll_rad: float, pitch_rad: float, motors_on: bool) -> bool:
        """True when the motors must be cut now: running, and tilted beyond the limit for ``hold_s``."""
        tilt = tilt_deg(roll_rad, pitch_rad)
        if not motors_on or not math.isfinite(tilt) or tilt <= self.max_tilt_deg:
            self._since = None
            return False
        self._since = now if self._since is None else self._since
        if now - self._since < self.hold_s:
            return False
        self._since = None
        self.reason = (f"tumbling: estimate tilted {tilt:.0f}° (roll {math.degrees(roll_rad):.0f}°, pitch "
                       f"{math.degrees(pitch_rad):.0f}°) for {self.hold_s:g} s, beyond CUT_TILT_DEG "
                       f"{self.max_tilt_deg:g}°: motors cut")
        return True


@dataclass
class FallWatch:
    """From a tumble cut until the quadrotor rests: the gyro below ``rest_rate_rad_s`` and the specific force
    within ``rest_acc_dev`` of 1 g (free fall reads 0 g, a tumble turns) for ``rest_s``. The motors being off,
    nothing else tells a fall from a quadrotor lying on the ground."""

    rest_rate_rad_s: float = 0.3
    rest_acc_dev: float = 0.1
    rest_s: float = 0.5
    falling: bool = False
    _still_since: float | None = None

    def cut(self) -> None:
        """The motors were cut in the air: falling from now on."""
        self.falling = True
        self._still_since = None

    def update(self, now: float, gyro_norm_rad_s: float, acc_norm_dev: float) -> bool:
        """Whether still falling after this sample."""
        if not self.falling:
            return False
        if gyro_norm_rad_s <= self.rest_rate_rad_s and abs(acc_norm_dev) <= self.rest_acc_dev:
            self._still_since = now if self._still_since is None else self._still_since
            if now - self._still_since >= self.rest_s:
                self.falling = False
                self._still_since = None
        else:
            self._still_since = None
        return self.falling
