"""Errors of the DSP link: each one says which port or which command, so an operator knows what to fix."""

from __future__ import annotations

from enum import IntEnum

from modules.dsp.protocol import error_name


class LinkErrorCode(IntEnum):
    """Codes the DSP process reports on its ``errors`` slot for failures on the PC side of the line.

    DSP error codes (0-99, docs/dsp_protocol.md §7) come from the DSP itself; these start at 100.
    """

    NO_ACK = 100  # a command was not acknowledged after its retries
    LINK_DOWN = 101  # the port is missing, busy or failed
    OVER_MAX_SPEED = 102  # SET_SPEED above the .conf MAX_SPEED: the batch was not sent
    FLUSHED = 103  # commands of a batch were dropped, unsent, by an ABORT
    NOT_OWNER = 104  # a sender's batch holds a command class it does not own (bbcs.contracts.dsp): not sent


class DspLinkError(RuntimeError):
    """The serial link cannot be used: port missing, busy, not permitted, closed or failed."""


class DspTimeout(DspLinkError):
    """A command was not acknowledged after its last retry (DSP silent, wrong baud, cable)."""

    def __init__(self, command: str, seq: int, attempts: int, timeout_s: float, port: str) -> None:
        self.command = command
        self.seq = seq
        self.attempts = attempts
        super().__init__(f"no acknowledgement from the DSP on {port} for {command} (seq {seq}) after "
                         f"{attempts} attempts of {timeout_s:g} s each: is the DSP powered, the cable in and "
                         f"the baud rate right?")


class DspRejected(DspLinkError):
    """The DSP acknowledged a command with a non-zero status: it refused it and changed nothing."""

    def __init__(self, command: str, status: int) -> None:
        self.command = command
        self.status = status
        super().__init__(f"the DSP refused {command}: {error_name(status)} (status {status})")
