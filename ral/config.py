"""The RAL's configuration: its manifest parameters (:class:`RalConfig`, checked by ``cromat launch --check``)
and the constants its rooms share."""

from __future__ import annotations

import msgspec

from bbcs import InvalidNameError, keys, raise_first, struct_param_errors
from bbcs.contracts import mri
from bbcs.contracts.dsp import FORWARDED_DSP_ERROR_BASE, MAX_SPEED_LIMIT, LinkErrorCode
from ral.failsafe import FailsafeAction

MAX_ERRORS = 20
HARMLESS_CODES = frozenset({FORWARDED_DSP_ERROR_BASE + LinkErrorCode.FLUSHED})
"""Module errors that do not affect a running task (unsent commands dropped because an abort overtook them)."""
MANAGER_STALE_S = 3.0
TASKS_REFRESH_S = 1.0
RESTART_REPLY_S = 4.0
"""A module restart is answered within this, below a ground station's default 5 s wait: as the manager confirmed
it by then, else as under way (its outcome follows as a ``module_restarted`` event or an error)."""
RESTART_CONFIRM_S = 60.0
"""How long the manager's confirmation of a restart is awaited (it answers once the module is up and linked)."""


class RalConfig(msgspec.Struct, frozen=True, kw_only=True):
    """The RAL's manifest parameters (``params`` of its module entry; ``task.<kind> = <manifest task>``)."""

    failsafe_action: FailsafeAction = FailsafeAction.HOLD
    failsafe_timeout_s: float = 10.0
    heartbeat_timeout_s: float = 2.0
    regain_s: float = 1.0
    position_tolerance_m: float = 3.0
    altitude_tolerance_m: float = 2.0
    settle_s: float = 2.0
    max_range_m: float = 20_000.0
    stall_s: float = 30.0
    """A movement task that makes no progress for this long fails (task_failed)."""
    mri_timeout_s: float = mri.REPLY_TIMEOUT_S
    """Must exceed the manager's ack wait (``mri.MANAGER_ACK_S``), else a task can be applied after being refused."""
    state_period_s: float = 0.2
    speed_ack_s: float = 3.0
    """How long the RAL waits for the answer to a path's speed before the path is not sent."""
    speed_ack_from: str = ""
    """The module whose ``speed_ack`` slot answers the RAL's speeds (the UAV: ``path_follower``); empty: the robot's
    speed and path reach one consumer in order and nothing is waited for (the manifest says which)."""
    kind: str = ""
    """Robot kind shown in the GRI state when the manager's state has none."""
    planner: str = "trajectory"
    """The module that plans survey and orbit paths: the RAL writes its ``request`` input and reads its ``status``,
    ``survey`` and ``orbit`` outputs (docs/trajectory.md). Empty: none, and a survey or orbit is refused."""
    refs_to: str = "path_follower"
    """The module whose ``refs`` input takes a bridge task's references (REFS is not routed: the seed's
    CONTROL_ENTRADA has no field for it). Empty: none, and a bridge task is refused."""
    fleet_can_do: str = ""
    """Fleet target kinds this robot bids on, comma-separated (``none``: never); empty: ``visit`` if it has goto."""
    fleet_bid_window_s: float = 2.0
    """Longest wait for every live RAL's bid before a fleet round is decided without it (ral/fleet.py)."""
    battery_full_v: float = 0.0
    """Pack voltage at a full charge (the UAV's 6S LiPo: 25.2 V); with ``battery_empty_v``, turns the telemetry's
    ``battery_v`` into the state of charge a fleet bid weighs (ral/fleet.py ``state_of_charge``). 0: no estimate,
    bids carry no battery."""
    battery_empty_v: float = 0.0
    """Pack voltage taken as empty (below the full one)."""
    fleet_ca: str = ""
    """Set by the launch on a secured robot (``[bus.tls]``): the fleet CA (PEM) a ground station's certificate must
    be issued by for this RAL to adopt a fleet task it signed (bbcs/signing.py). Empty on a TLS bus: the bus's CA."""
    fleet_signers: str = ""
    """Set by the launch with ``fleet_ca``: the ground-station identities (``[bus.tls] gcs``, comma-separated) whose
    signature makes a fleet task adoptable; none on a TLS bus: every fleet task is refused."""
    fleet_crl: str = ""
    """Set by the launch with ``fleet_ca``: the fleet CA's revocation list (PEM, ``cromat certs --revoke``); a
    station whose certificate it lists signs nothing this RAL adopts. Read again when the file changes; missing:
    nothing revoked."""
    sync_clock_offset_s: float = 0.0
    """Tests only: this robot's fleet-time clock runs this far from the host's (docs/sync.md)."""
    sync_clock_drift_ppm: float = 0.0
    """Tests only: and drifts this much (parts per million)."""

    @classmethod
    def param_errors(cls, params: dict[str, str]) -> list[tuple[str, str]]:
        """Every problem of the manifest's RAL ``params``, (key, reason) (``cromat launch --check``: file:line)."""
        plain = {k: v for k, v in params.items() if not k.startswith("task.")}
        errors = struct_param_errors(cls, plain, what="RAL")
        if errors:
            return errors
        cfg = msgspec.convert(plain, cls, strict=False)
        for key in ("speed_ack_from", "planner", "refs_to"):
            value = getattr(cfg, key)
            try:
                if value:
                    keys.validate_name(value, "module name")
            except InvalidNameError as exc:
                errors.append((key, f"bad RAL parameter: {key}: {exc}"))
        if (cfg.battery_full_v or cfg.battery_empty_v) and not 0.0 <= cfg.battery_empty_v < cfg.battery_full_v <= 100.0:
            errors.append(("battery_full_v" if "battery_full_v" in plain else "battery_empty_v", (
                f"bad RAL parameter: battery_empty_v = {cfg.battery_empty_v:g} and battery_full_v = "
                f"{cfg.battery_full_v:g} must be volts with 0 <= empty < full <= 100 (both, or neither)")))
        if cfg.mri_timeout_s <= mri.MANAGER_ACK_S:
            errors.append(("mri_timeout_s", (
                f"bad RAL parameter: mri_timeout_s = {cfg.mri_timeout_s:g} must exceed the manager's ack wait "
                f"({mri.MANAGER_ACK_S:g} s), or a task could be applied after the ground station was told it failed")))
        return errors

    @classmethod
    def from_params(cls, params: dict[str, str]) -> tuple[RalConfig, dict[str, str]]:
        """The RAL's configuration; a :class:`bbcs.params.ParamError` (exit ``EXIT_CONFIG``: not restarted) naming
        every problem :meth:`param_errors` finds."""
        raise_first(cls.param_errors(params), source="manifest params of the RAL")
        plain = {k: v for k, v in params.items() if not k.startswith("task.")}
        names = {k.removeprefix("task."): v for k, v in params.items() if k.startswith("task.")}
        cfg = msgspec.convert(plain, cls, strict=False)
        return cfg, names


END_EVENTS = {
    "completed": "task_completed",
    "cancelled": "task_cancelled",
    "replaced": "task_replaced",
    "aborted": "aborted",
    "failed": "task_failed",
    "running": "task_accepted",
}


def p_max_speed() -> float:
    """Without a robot .conf, the protocol's ceiling is the only speed limit known."""
    return MAX_SPEED_LIMIT
