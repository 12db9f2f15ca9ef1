"""The motor driver (the seed's ``cmd``), its own process: controller commands in, ESC set-points out.

Decision logic is :class:`DriverLogic` (pure, injected clock). Rules (seed 002 §1.2.7):
- a command with any speed outside [MOTOR_MIN, MOTOR_MAX] is refused (ack OUT_OF_RANGE), the previous
  set-point stays; all four zero is the stop command;
- starting from stopped, the motors ramp from 0 to MOTOR_MIN over MOTOR_RAMP_S, the values jumping above and
  below the ramp (what made the real motors start), then follow the commands;
- every command gets an ack carrying its sequence number, so the sender knows the driver is alive;
- the last set-point is sent to the ESCs every MOTOR_SEND_PERIOD (they stop when set-points stop);
- no command for MOTOR_CMD_TIMEOUT → the motors are stopped. A refused command is a command: it keeps the
  motors at the last good set-point. The timeout is for a controller gone silent (the seed: the motors stop when
  commands stop); a refusal is reported in its ack, an error the seed says stops the flight, and the controller's
  MOTOR_ERROR_ACTION stops it (``land`` needs the motors: stopping them 0.5 s into a stream of refusals dropped
  the aircraft instead).

Process: ``python -m modules.uquad.motor_driver --conf C --listen 127.0.0.1:P --esc HOST:PORT [--lockstep]``.

With ``--lockstep`` (the simulator's lockstep, docs/uquad.md) the driver forwards exactly one set-point per
command and no keep-alive, and its clock is the commands' (one control period, 10 ms × CONTROL_EVERY, each): the
ramp lasts MOTOR_RAMP_S of simulated time whatever the load. Its silence timeout cannot fire on that clock; a
controller gone silent is stopped by the simulated ESCs' own timeout, on simulated time. A lockstep launch
(``CROMAT_SIM`` in its environment: the simulator steps on the bus barrier) implies ``--lockstep``: the barrier
counts one set-point per command.
"""

from __future__ import annotations

import argparse
import enum
import os
import select
import signal
import socket
import sys
import time
from dataclasses import dataclass

from bbcs.lockstep import SIM_ENV
from modules.uquad import motor_protocol as mp
from modules.uquad.motor_protocol import AckStatus


class DriverState(enum.Enum):
    STOPPED = "stopped"
    RAMPING = "ramping"
    RUNNING = "running"


@dataclass
class DriverLogic:
    min_speed: float
    max_speed: float
    ramp_s: float
    cmd_timeout_s: float
    zigzag: float = 0.15
    """Fraction of MOTOR_MIN the ramp values jump above and below the ramp."""

    def __post_init__(self) -> None:
        self.state = DriverState.STOPPED
        self.target = [0.0] * 4
        self._ramp_start = 0.0
        self._last_cmd = 0.0
        self._flip = 1.0
        self.refused = 0
        self.timeouts = 0

    def on_command(self, now: float, speeds: tuple[float, ...]) -> AckStatus:
        if all(s == 0.0 for s in speeds):
            self.state = DriverState.STOPPED
            self.target = [0.0] * 4
            self._last_cmd = now
            return AckStatus.STOPPED
        if any(not self.min_speed <= s <= self.max_speed for s in speeds):
            self.refused += 1
            self._last_cmd = now  # the controller is alive: the refusal is its error to act on, not a silence
            return AckStatus.OUT_OF_RANGE
        self._last_cmd = now
        self.target = list(speeds)
        if self.state is DriverState.STOPPED:
            self.state = DriverState.RAMPING
            self._ramp_start = now
        self._advance(now)
        return AckStatus.RAMPING if self.state is DriverState.RAMPING else AckStatus.OK

    def _advance(self, now: float) -> None:
        if self.state is not DriverState.STOPPED and now - self._last_cmd > self.cmd_timeout_s:
            self.state = DriverState.STOPPED
            self.target = [0.0] * 4
            self.timeouts += 1
        if self.state is DriverState.RAMPING and now - self._ramp_start >= self.ramp_s:
            self.state = DriverState.RUNNING

    def output(self, now: float) -> list[float]:
        """The set-point to send to the ESCs now."""
        self._advance(now)
        if self.state is DriverState.STOPPED:
            return [0.0] * 4
        if self.state is DriverState.RAMPING:
            base = self.min_speed * (now - self._ramp_start) / self.ramp_s
            self._flip = -self._flip
            value = min(self.min_speed, max(0.0, base + self._flip * self.zigzag * self.min_speed))
            return [value] * 4
        return list(self.target)


class DriverProcess:
    """Serves one controller on ``listen``; keeps a TCP link to the ESCs at ``esc`` (reconnecting)."""

    def __init__(self, logic: DriverLogic, listen: tuple[str, int], esc: tuple[str, int],
                 send_period: float, command_period: float | None = None) -> None:
        self.logic = logic
        self.listener = socket.create_server(listen)
        self.listener.setblocking(False)
        self.esc_addr = esc
        self.esc: socket.socket | None = None
        self.client: socket.socket | None = None
        self.parser = mp.FrameParser("M")
        self.send_period = send_period
        self.command_period = command_period
        """Lockstep: each command advances the driver's clock by this much, and nothing is sent between them."""
        self._commands = 0
        self._stop = False
        self.esc_errors = 0
        self.esc_dropped = 0

    @property
    def address(self) -> tuple[str, int]:
        return self.listener.getsockname()[:2]

    def stop(self) -> None:
        self._stop = True

    def _connect_esc(self) -> None:
        try:
            sock = socket.create_connection(self.esc_addr, timeout=0.05)
        except OSError:
            return
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(False)
        self.esc = sock

    def _send_esc(self, speeds: list[float]) -> bool:
        if self.esc is None:
            self._connect_esc()
        if self.esc is None:
            return False
        try:
            self.esc.send(mp.esc(speeds))
            return True
        except (BlockingIOError, InterruptedError):
            self.esc_dropped += 1  # the ESC end is not draining: this set-point is lost, the next one follows
            return True
        except OSError:
            self.esc.close()
            self.esc = None
            self.esc_errors += 1
            return False

    def _on_client_data(self, data: bytes) -> None:
        assert self.client is not None
        for frame in self.parser.feed(data):
            seq = frame.fields[0]
            self._commands += 1
            now = time.monotonic() if self.command_period is None else self._commands * self.command_period
            status = self.logic.on_command(now, mp.speeds(frame))
            forward = status in (AckStatus.OK, AckStatus.RAMPING, AckStatus.STOPPED)
            # in lockstep a refused command still gets its set-point (the last good one): the simulator waits for it
            if forward or self.command_period is not None:
                if not self._send_esc(self.logic.output(now)) and forward:
                    status = AckStatus.ESC_ERROR
            try:
                self.client.send(mp.ack(seq, status))
            except OSError:
                pass

    def run(self) -> None:
        next_send = time.monotonic()
        while not self._stop:
            fds = [self.listener] + ([self.client] if self.client else []) + ([self.esc] if self.esc else [])
            wait = 0.5 if self.command_period is not None else max(0.0, next_send - time.monotonic())
            ready, _, _ = select.select(fds, [], [], wait)
            for sock in ready:
                if sock is self.listener:
                    conn, _ = self.listener.accept()
                    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    if self.client is not None:
                        self.client.close()
                    self.client = conn
                elif sock is self.client:
                    data = b""
                    try:
                        data = sock.recv(4096)
                    except OSError:
                        pass
                    if data:
                        self._on_client_data(data)
                    else:
                        self.client.close()
                        self.client = None
                elif sock is self.esc:
                    try:
                        if not sock.recv(4096):
                            raise OSError("ESC link closed")
                    except OSError:
                        sock.close()
                        self.esc = None
                        self.esc_errors += 1
            now = time.monotonic()
            if self.command_period is None and now >= next_send:
                self._send_esc(self.logic.output(now))
                next_send = max(next_send + self.send_period, now)
        self._send_esc([0.0] * 4)  # leaving: the motors stop

    def close(self) -> None:
        for sock in (self.client, self.esc, self.listener):
            if sock is not None:
                sock.close()


def _addr(spec: str) -> tuple[str, int]:
    spec = spec.removeprefix("tcp://")
    host, _, port = spec.rpartition(":")
    return host or "127.0.0.1", int(port)


def main(argv: list[str] | None = None) -> int:
    from modules.uquad.config import load_config

    ap = argparse.ArgumentParser(prog="python -m modules.uquad.motor_driver", description="uQuad motor driver")
    ap.add_argument("--conf", required=True)
    ap.add_argument("--listen", default="127.0.0.1:0")
    ap.add_argument("--esc", required=True, help="host:port of the ESCs (the simulator's esc end)")
    ap.add_argument("--lockstep", action="store_true",
                    help="one ESC set-point per command, timed by the commands (the simulator's --lockstep)")
    args = ap.parse_args(argv)
    v = load_config(args.conf).values
    logic = DriverLogic(v.MOTOR_MIN, v.MOTOR_MAX, v.MOTOR_RAMP_S, v.MOTOR_CMD_TIMEOUT)
    lockstep = args.lockstep or bool(os.environ.get(SIM_ENV))
    command_period = 0.01 * v.CONTROL_EVERY if lockstep else None
    proc = DriverProcess(logic, _addr(args.listen), _addr(args.esc), v.MOTOR_SEND_PERIOD, command_period)
    signal.signal(signal.SIGTERM, lambda *_: proc.stop())
    signal.signal(signal.SIGINT, lambda *_: proc.stop())
    host, port = proc.address
    print(f"uquad motor driver ready tcp://{host}:{port}", flush=True)
    try:
        proc.run()
    finally:
        proc.close()
        print(f"uquad motor driver stopped refused={logic.refused} timeouts={logic.timeouts} "
              f"esc_errors={proc.esc_errors} esc_dropped={proc.esc_dropped}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
