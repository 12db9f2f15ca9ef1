"""The controller's side of the motor driver link (the seed's ``motor`` library): clamp, send, check acks.

The controller never sends a value outside [MOTOR_MIN, MOTOR_MAX] once the motors run (it clamps); a stop is
all four zero. Every command must be acknowledged within MOTOR_ACK_TIMEOUT; a refused command, an ESC error or
a missing ack is a driver error (``error`` says which), which the flight loop answers per MOTOR_ERROR_ACTION.

A *late* ack alone (the driver answers again, every command in time) is the one error that clears, and only on
the ground with the motors stopped, after ``RECOVERY_S`` of acks in time (:meth:`MotorClient.recover`): on a loaded
computer one late ack otherwise grounded the robot until its process restarted. A refusal, an ESC error, a closed
link or an ack never received stays.
"""

from __future__ import annotations

import socket
from collections import OrderedDict

import numpy as np

from modules.uquad import motor_protocol as mp
from modules.uquad.motor_protocol import AckStatus

RECOVERY_S = 2.0
"""Seconds (of the link's clock) of every command acknowledged in time before a late-ack error clears."""


class MotorClient:
    def __init__(self, sock: socket.socket, min_speed: float, max_speed: float, ack_timeout_s: float) -> None:
        self.sock = sock
        if sock.family in (socket.AF_INET, socket.AF_INET6):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(False)
        self.min_speed = min_speed
        self.max_speed = max_speed
        self.ack_timeout_s = ack_timeout_s
        self.parser = mp.FrameParser("K")
        self.seq = 0
        self.pending: OrderedDict[int, float] = OrderedDict()
        self.error: str = ""
        self.error_is_late_ack = False
        """The error is only an ack that came too late (the one that :meth:`recover` may clear)."""
        self.in_time_since: float | None = None
        """Link time since which no command has waited longer than the ack timeout (None: one does now)."""
        self.acks = 0
        self.last_status: AckStatus | None = None
        self.sent = 0

    def fileno(self) -> int:
        return self.sock.fileno()

    def send(self, now: float, speeds: np.ndarray | list[float]) -> list[float]:
        """Send (clamped to [min, max], or a stop when all are 0); returns what was sent."""
        values = [0.0] * 4 if not np.any(speeds) else [float(np.clip(s, self.min_speed, self.max_speed))
                                                        for s in speeds]
        self.seq = (self.seq + 1) & 0xFFFF
        try:
            self.sock.send(mp.command(self.seq, values))
        except OSError as exc:
            self._fail(f"motor driver link: {exc}")
            return values
        self.pending[self.seq] = now
        self.sent += 1
        return values

    def on_readable(self, now: float) -> None:
        try:
            data = self.sock.recv(4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            data = b""
            self._fail(f"motor driver link: {exc}")
        if not data:
            self._fail("motor driver closed the link")
            return
        for frame in self.parser.feed(data):
            seq, status = frame.fields
            self.pending.pop(seq, None)
            self.acks += 1
            self.last_status = AckStatus(status)
            if status in (AckStatus.OUT_OF_RANGE, AckStatus.ESC_ERROR):
                self._fail(f"motor driver reported {AckStatus(status).name} (command {seq})")

    def check(self, now: float) -> str:
        """The driver error so far ('' when none): also a command not acknowledged in time."""
        late = None
        if self.pending:
            seq, sent_at = next(iter(self.pending.items()))
            if now - sent_at > self.ack_timeout_s:
                late = seq
        if late is None:
            if self.in_time_since is None:
                self.in_time_since = now
        else:
            self.in_time_since = None
            if not self.error:
                self.error = f"no ack for command {late} within {self.ack_timeout_s * 1000:.0f} ms"
                self.error_is_late_ack = True
        return self.error

    def recover(self, now: float, hold_s: float = RECOVERY_S) -> bool:
        """Clear a late-ack error once every command has been acknowledged in time for ``hold_s`` (the caller
        asks only on the ground with the motors stopped); True when it cleared. Any other error stays."""
        if not (self.error and self.error_is_late_ack) or self.in_time_since is None:
            return False
        if now - self.in_time_since < hold_s:
            return False
        self.error, self.error_is_late_ack = "", False
        return True

    def _fail(self, why: str) -> None:
        """An error that never clears (it replaces a late-ack error: the driver is now known to be faulty)."""
        if not self.error or self.error_is_late_ack:
            self.error, self.error_is_late_ack = why, False

    def close(self) -> None:
        self.sock.close()
