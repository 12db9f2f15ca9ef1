"""Who may command the DSP: one command key per sending module, and the command classes each one owns.

The router's access control decides on key expressions and identities, never on payloads, so "only the module
that owns a command class may send it" is split in two checks that hold together (docs/security.md):

1. each sender has its own command key, ``cromat/<robot>/dsp/commands_<sender>``; the router lets only the
   identity ``<sender>`` put there (:mod:`bbcs.acl`), so the key names the sender, authenticated;
2. the DSP process reads each sender's key and sends a batch only if every command's class is in
   :data:`COMMAND_RIGHTS` for that key's sender; the ``sender`` field inside the batch is not trusted.

The DSP's own start-up commands (telemetry mask, helicopter type, PID groups) are owned by nobody on the bus.
"""

from __future__ import annotations

COMMANDS_SLOT_PREFIX = "commands_"

COMMAND_RIGHTS: dict[str, frozenset[str]] = {
    "pan_tilt": frozenset({"SetPanTiltMode", "SetPanTiltAngles", "SetPanTiltTarget"}),
    "path_follower": frozenset({"SetMode", "SetSpeed", "SetHeading", "AddWaypoint", "SetRefs", "SetTracking",
                                "InvalidatePath", "Abort"}),
}
"""Sending module (instance name) → DSP command classes (struct names) it owns."""


def commands_slot(sender: str) -> str:
    """The DSP's input slot (and the key's last chunk) for ``sender``'s command batches."""
    return COMMANDS_SLOT_PREFIX + sender


def refused_classes(sender: str, class_names: list[str]) -> list[str]:
    """The command classes in a batch from ``sender`` that it does not own (empty: the batch may be sent)."""
    owned = COMMAND_RIGHTS.get(sender, frozenset())
    return [name for name in dict.fromkeys(class_names) if name not in owned]
