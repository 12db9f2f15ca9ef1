"""Link-loss failsafe at the module-bus level: a pure state machine driven by an injected clock.

The RAL feeds it the ground stations' liveliness tokens and heartbeats and calls :meth:`LinkMonitor.update`
periodically. The link is *up* while at least one GCS token is alive **and** a heartbeat arrived within
``heartbeat_timeout_s`` (a token alone can outlive a hung GCS; a heartbeat alone says nothing about a GCS that
left cleanly). After ``loss_timeout_s`` of continuous loss the configured action is due, once. The link counts
as regained only after ``regain_s`` of continuous link (hysteresis), and regaining never resumes the mission:
the failsafe action stays in force until a ground station sends a new task.

An operator's new task ends the failsafe (:meth:`LinkMonitor.clear_failsafe`): the machine goes back to
``no_gcs`` (the operator who sent it holds no link, or the regain would already have ended it), so nothing is armed
until a station links again, and the robot counts as available to the fleet again.

```
no_gcs ──link──▶ up ──loss──▶ lost ──loss_timeout──▶ failsafe
                  ▲             │ link for regain_s      │ link for regain_s
                  └─────────────┴────────────────────────┘  (event link_regained)
failsafe ──operator's new task──▶ no_gcs
```
Nothing is armed before the first GCS link: a robot started with no ground station does not trigger it.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Literal

LinkState = Literal["no_gcs", "up", "lost", "failsafe"]


class FailsafeAction(enum.StrEnum):
    HOLD = "hold"
    RETURN = "return"
    LAND = "land"


@dataclass(frozen=True)
class FailsafeConfig:
    loss_timeout_s: float = 10.0
    """Continuous link loss before the action runs (PX4's default data-link loss timeout is 10 s)."""
    heartbeat_timeout_s: float = 2.0
    regain_s: float = 1.0
    action: FailsafeAction = FailsafeAction.HOLD

    def __post_init__(self) -> None:
        for name in ("loss_timeout_s", "heartbeat_timeout_s", "regain_s"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"failsafe {name} must be >= 0, got {getattr(self, name)!r}")
        object.__setattr__(self, "action", FailsafeAction(self.action))


@dataclass(frozen=True)
class LinkEvent:
    kind: Literal["link_up", "link_lost", "failsafe", "link_regained"]
    detail: str
    action: FailsafeAction | None = None
    """Set on ``failsafe``: what the RAL must now do."""


@dataclass
class LinkMonitor:
    config: FailsafeConfig
    state: LinkState = "no_gcs"
    tokens: set[str] = field(default_factory=set)
    last_heartbeat: float | None = None
    lost_since: float | None = None
    ok_since: float | None = None

    def token(self, gcs: str, alive: bool) -> None:
        """A GCS liveliness token appeared (``alive``) or disappeared."""
        if alive:
            self.tokens.add(gcs)
        else:
            self.tokens.discard(gcs)

    def heartbeat(self, now: float) -> None:
        self.last_heartbeat = now if self.last_heartbeat is None else max(self.last_heartbeat, now)

    def link_ok(self, now: float) -> bool:
        return (
            bool(self.tokens)
            and self.last_heartbeat is not None
            and now - self.last_heartbeat <= self.config.heartbeat_timeout_s
        )

    @property
    def in_force(self) -> bool:
        """The failsafe ran and no operator task has replaced it since (the fleet counts the robot unavailable)."""
        return self.state == "failsafe"

    def clear_failsafe(self) -> bool:
        """An operator's task was accepted: a failsafe in force ends (True); otherwise nothing changes."""
        if self.state != "failsafe":
            return False
        self.state = "no_gcs"
        self.lost_since = None
        self.ok_since = None
        return True

    def update(self, now: float) -> list[LinkEvent]:
        """Advance the machine to ``now``; the returned events are what the RAL reports (and does)."""
        ok = self.link_ok(now)
        cfg = self.config
        if self.state == "no_gcs":
            if ok:
                self.state = "up"
                return [LinkEvent("link_up", f"ground station(s) {', '.join(sorted(self.tokens))} linked")]
            return []
        if self.state == "up":
            if not ok:
                self.state = "lost"
                self.lost_since = now
                self.ok_since = None
                why = "no GCS liveliness token" if not self.tokens else "no GCS heartbeat"
                return [LinkEvent("link_lost", f"{why}; failsafe '{cfg.action}' in {cfg.loss_timeout_s:g} s")]
            return []
        # lost or failsafe: wait for a steady link, or for the timeout
        if ok:
            if self.ok_since is None:
                self.ok_since = now
            if now - self.ok_since >= cfg.regain_s:
                was = self.state
                self.state = "up"
                self.lost_since = None
                self.ok_since = None
                if was == "failsafe":
                    return [
                        LinkEvent("link_regained", f"failsafe '{cfg.action}' stays in force until a new task")
                    ]
                return [
                    LinkEvent("link_regained", "link back before the failsafe timeout; mission unchanged")
                ]
            return []
        self.ok_since = None
        assert self.lost_since is not None
        if self.state == "lost" and now - self.lost_since >= cfg.loss_timeout_s:
            self.state = "failsafe"
            return [
                LinkEvent(
                    "failsafe",
                    f"no ground station for {now - self.lost_since:.1f} s: {cfg.action}",
                    action=cfg.action,
                )
            ]
        return []
