"""Lost-target state machine with hysteresis; time is passed in (``now``), never read from a clock.

States and transitions (a "hit" is a detection whose confidence reaches the threshold of the state):

    LOST       --hit (>= confidence_on)-------------------------------------> TENTATIVE
    TENTATIVE  --hit (>= confidence_on), >= confirm_hits hits over >= confirm_s--> FOUND
    TENTATIVE  --miss (no detection or confidence < confidence_on)-----------> LOST
    FOUND      --hit (>= confidence_off, the lower threshold)-----------------> FOUND (refreshes last hit)
    FOUND      --no hit for >= lose_s------------------------------------------> LOST

So a target must be seen consistently to be acquired, and short dropouts or weak frames do not lose it.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass


class TrackState(enum.Enum):
    LOST = "lost"
    TENTATIVE = "tentative"
    FOUND = "found"


@dataclass(frozen=True)
class TrackerConfig:
    """Hysteresis thresholds (confidence in [0, 1]) and times (seconds)."""

    confidence_on: float = 0.5
    confidence_off: float = 0.3
    confirm_hits: int = 3
    confirm_s: float = 0.1
    lose_s: float = 1.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.confidence_off <= self.confidence_on <= 1.0:
            raise ValueError(
                f"need 0 <= confidence_off ({self.confidence_off}) <= confidence_on ({self.confidence_on}) <= 1"
            )
        if self.confirm_hits < 1:
            raise ValueError(f"confirm_hits {self.confirm_hits} must be >= 1")
        if not (self.confirm_s >= 0.0 and self.lose_s > 0.0):
            raise ValueError("confirm_s must be >= 0 and lose_s > 0")


class TargetTracker:
    """Feeds on one confidence (or None) per frame; ``update`` returns the new state."""

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config if config is not None else TrackerConfig()
        self.reset()

    @property
    def coasting(self) -> bool:
        """FOUND but the latest frame was not a hit (holding on through a dropout)."""
        return self.state is TrackState.FOUND and not self.hit

    def reset(self) -> None:
        """Back to LOST, forgetting everything (time too)."""
        self.state = TrackState.LOST
        self.last_hit: float | None = None
        self.hit = False
        self._since: float | None = None
        self._hits = 0
        self._now: float | None = None

    def update(self, confidence: float | None, now: float) -> TrackState:
        """Advance with this frame's detection confidence (None = nothing detected) at time ``now``."""
        if not math.isfinite(now):
            raise ValueError(f"time {now!r} is not finite")
        if self._now is not None and now < self._now:
            raise ValueError(f"time went backwards: {now} < {self._now}")
        if confidence is not None and not (math.isfinite(confidence) and 0.0 <= confidence <= 1.0):
            raise ValueError(f"confidence {confidence!r} outside [0, 1]")
        self._now = now
        cfg = self.config
        strong = confidence is not None and confidence >= cfg.confidence_on
        if self.state is TrackState.FOUND:
            self.hit = confidence is not None and confidence >= cfg.confidence_off
        else:
            self.hit = strong
        if self.hit:
            self.last_hit = now

        if self.state is TrackState.LOST:
            if self.hit:
                self._enter_tentative(now)
        elif self.state is TrackState.TENTATIVE:
            if not self.hit:
                self.state = TrackState.LOST
            else:
                self._hits += 1
        elif not self.hit and self.last_hit is not None and now - self.last_hit >= cfg.lose_s:
            self.state = TrackState.LOST
        if (
            self.state is TrackState.TENTATIVE
            and self._since is not None
            and self._hits >= cfg.confirm_hits
            and now - self._since >= cfg.confirm_s
        ):
            self.state = TrackState.FOUND
        return self.state

    def _enter_tentative(self, now: float) -> None:
        self.state = TrackState.TENTATIVE
        self._since = now
        self._hits = 1
