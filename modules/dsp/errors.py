"""Errors of the DSP link: each one says which port or which command, so an operator knows what to fix."""

from __future__ import annotations

from bbcs.contracts.dsp import dsp_error_name


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


class DspPreempted(DspLinkError):
    """An ABORT took the line while this command waited for its acknowledgement: it may or may not have been
    carried out, and the ABORT that follows empties the DSP's queue either way."""

    def __init__(self, command: str, seq: int) -> None:
        self.command = command
        self.seq = seq
        super().__init__(f"{command} (seq {seq}) not acknowledged before an ABORT took the line")


class DspRejected(DspLinkError):
    """The DSP acknowledged a command with a non-zero status: it refused it and changed nothing."""

    def __init__(self, command: str, status: int) -> None:
        self.command = command
        self.status = status
        super().__init__(f"the DSP refused {command}: {dsp_error_name(status)} (status {status})")
