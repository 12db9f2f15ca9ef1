"""The controller's side of the motor driver link (the seed's ``motor`` library): clamp, send, check acks.

The controller never sends a value outside [MOTOR_MIN, MOTOR_MAX] once the motors run (it clamps); a stop is
all four zero. Every command must be acknowledged within MOTOR_ACK_TIMEOUT; a refused command, an ESC error or
a missing ack is a driver error (``error`` says which), which the flight loop answers per MOTOR_ERROR_ACTION.
"""

from __future__ import annotations

import socket
from collections import OrderedDict

import numpy as np

from modules.uquad import motor_protocol as mp
from modules.uquad.motor_protocol import AckStatus


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
            self.error = self.error or f"motor driver link: {exc}"
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
            self.error = self.error or f"motor driver link: {exc}"
        if not data:
            self.error = self.error or "motor driver closed the link"
            return
        for frame in self.parser.feed(data):
            seq, status = frame.fields
            self.pending.pop(seq, None)
            self.acks += 1
            self.last_status = AckStatus(status)
            if status in (AckStatus.OUT_OF_RANGE, AckStatus.ESC_ERROR):
                self.error = self.error or f"motor driver reported {AckStatus(status).name} (command {seq})"

    def check(self, now: float) -> str:
        """The driver error so far ('' when none): also a command not acknowledged in time."""
        if not self.error and self.pending:
            seq, sent_at = next(iter(self.pending.items()))
            if now - sent_at > self.ack_timeout_s:
                self.error = f"no ack for command {seq} within {self.ack_timeout_s * 1000:.0f} ms"
        return self.error

    def close(self) -> None:
        self.sock.close()
