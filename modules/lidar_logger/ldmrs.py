"""LD-MRS TCP driver: connect, configure with checked replies, start/stop measuring, receive scans.

A receiving thread owns the socket's input: it cuts the stream into messages, hands scans to ``on_scan``
(called in that thread, the seed's messageHandler) and routes command replies to whoever waits for them.
Every message it refuses (a damaged header, a scan cut short, a scan whose content is impossible) is counted and
reported to ``on_refused``, coalesced (modules/lidar_logger/refusals.py: the first at once, then at most one report
a second with the count).
Commands can be awaited (``command``) or only sent (``send_command``) so the logger can keep writing scans
while StopMeasure is on its way.
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from modules.lidar_logger.ldmrs_proto import (
    DEFAULT_PORT,
    OUTPUT_ERRORS,
    OUTPUT_SCAN,
    RESOLUTION_CONSTANT,
    Cmd,
    DataType,
    LdmrsProtocolError,
    MessageParser,
    Param,
    Reply,
    command_payload,
    pack_message,
    parse_reply,
)
from modules.lidar_logger.ldmrs_scan import TICKS_PER_DEGREE, Scan, decode_scan, posix_to_ntp
from modules.lidar_logger.refusals import Refusals

log = logging.getLogger("lidar_logger.ldmrs")

FREQUENCIES = {12.5: 3200, 25.0: 6400, 50.0: 12800}


def ldmrs_link(host: str, port: int) -> str:
    """The LD-MRS's device link as both ends name it in a lockstep simulation's counts."""
    return f"ldmrs:{host}:{port}"


class LdmrsError(RuntimeError):
    """The scanner refused a command, did not answer, or the connection failed."""


@dataclass(frozen=True)
class ScannerConfig:
    """What the seed configures (ch. 4.2.3.2): +50°…-50°, 12.5 Hz, constant 0.25° resolution, scans on."""

    start_angle_deg: float = 50.0
    end_angle_deg: float = -50.0
    frequency_hz: float = 12.5
    resolution_type: int = RESOLUTION_CONSTANT
    output_flags: int = 0xFFFF & ~(OUTPUT_SCAN | OUTPUT_ERRORS)
    """Bits at 0 enable an output: scans and errors/warnings on Ethernet, nothing else."""

    def __post_init__(self) -> None:
        start, end = self.start_ticks, self.end_ticks
        if not start > end:
            raise ValueError(f"start angle {self.start_angle_deg}° must be greater than end angle "
                             f"{self.end_angle_deg}°")
        if start > 1600 or end < -1920:
            raise ValueError("LD-MRS angles must lie within +50° (start) and -60° (end)")
        if self.frequency_hz not in FREQUENCIES:
            raise ValueError(f"scan frequency {self.frequency_hz} Hz; the LD-MRS offers 12.5, 25 or 50 Hz")

    @property
    def start_ticks(self) -> int:
        return _even_ticks(self.start_angle_deg)

    @property
    def end_ticks(self) -> int:
        return _even_ticks(self.end_angle_deg)

    def parameters(self) -> list[tuple[Param, int]]:
        return [
            (Param.DATA_OUTPUT_FLAGS, self.output_flags),
            (Param.START_ANGLE, self.start_ticks & 0xFFFF),
            (Param.END_ANGLE, self.end_ticks & 0xFFFF),
            (Param.SCAN_FREQUENCY, FREQUENCIES[self.frequency_hz]),
            (Param.ANGULAR_RESOLUTION_TYPE, self.resolution_type),
        ]


def _even_ticks(deg: float) -> int:
    """Angle in 1/32° ticks, made even (libsick: some odd tick values stop the scanner sending scans)."""
    ticks = int(round(deg * TICKS_PER_DEGREE))
    return ticks - (ticks % 2)


def _signed16(v: int) -> int:
    return v - 0x10000 if v & 0x8000 else v


class PendingReply:
    def __init__(self, cmd: int) -> None:
        self.cmd = cmd
        self._event = threading.Event()
        self.reply: Reply | None = None

    def _set(self, reply: Reply) -> None:
        self.reply = reply
        self._event.set()

    def wait(self, timeout: float) -> Reply | None:
        self._event.wait(timeout)
        return self.reply

    @property
    def done(self) -> bool:
        return self._event.is_set()


@dataclass
class ScannerStatus:
    firmware: int
    fpga: int
    scanner_status: int
    temperature: int
    raw: bytes = field(repr=False)


class LdmrsClient:
    """One LD-MRS at ``host:port``."""

    def __init__(self, host: str, port: int = DEFAULT_PORT, *, connect_timeout: float = 5.0,
                 reply_timeout: float = 2.0, clock: Callable[[], float] = time.monotonic) -> None:
        self.host = host
        self.port = port
        self.connect_timeout = connect_timeout
        self.reply_timeout = reply_timeout
        self.on_scan: Callable[[Scan], None] | None = None
        self.on_refused: Callable[[str], None] | None = None
        """Called (receiver thread) with a report of the messages refused (cut short, damaged, impossible content),
        coalesced: the first at once, then at most one a second."""
        self.parser = MessageParser()
        self.refusals = Refusals("LD-MRS")
        self.clock = clock
        self._damaged_seen = 0
        self.scans = 0
        self.scans_ignored = 0
        self.bad_scans = 0
        self.errors_warnings = 0
        self.last_error_warning: tuple[int, int, int, int] | None = None
        self.unexpected_replies = 0
        self.handler_errors = 0
        self.disconnected: str | None = None
        self.bytes_tx = 0
        """Bytes sent to the scanner on this connection."""
        self.bytes_handled = 0
        """Bytes received from the scanner and handled: counted once every message they completed was dispatched
        (a scan handed to ``on_scan`` and back). A lockstep simulation compares it with what the simulator sent."""
        self._sock: socket.socket | None = None
        self._send_lock = threading.Lock()
        self._waiters: dict[int, deque[PendingReply]] = {}
        self._waiters_lock = threading.Lock()
        self._stop = threading.Event()
        self._rx: threading.Thread | None = None

    # --- connection ---

    def connect(self) -> None:
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
        except OSError as exc:
            raise LdmrsError(f"cannot connect to LD-MRS at {self.host}:{self.port}: {exc}") from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(0.2)
        self._sock = sock
        self._rx = threading.Thread(target=self._receive, name="ldmrs-rx", daemon=True)
        self._rx.start()

    def close(self) -> None:
        self._stop.set()
        if self._rx is not None:
            self._rx.join(timeout=5.0)
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _receive(self) -> None:
        assert self._sock is not None
        sock = self._sock
        while not self._stop.is_set():
            try:
                chunk = sock.recv(65536)
            except TimeoutError:
                self._note_damaged()  # a quiet link still reports what is pending
                continue
            except OSError as exc:
                self.disconnected = f"connection to LD-MRS lost: {exc}"
                break
            if not chunk:
                self.disconnected = "LD-MRS closed the connection"
                break
            for msg in self.parser.feed(chunk):
                self._dispatch(msg.data_type, msg.payload)
            self.bytes_handled += len(chunk)
            self._note_damaged()
        self._note_damaged()
        self._report(self.refusals.poll(float("inf")))
        self._fail_waiters()

    def _note_damaged(self) -> None:
        """Messages the stream parser refused since the last look, and any report left pending."""
        p = self.parser
        new = p.damaged - self._damaged_seen
        self._damaged_seen = p.damaged
        now = self.clock()
        if new:
            self.bad_scans += new
            self._report(self.refusals.note(now, f"message dropped (cut short {p.cut_short}, size disagreeing with "
                                                 f"its content {p.size_mismatch}, impossible size {p.bad_size})",
                                            new))
        else:
            self._report(self.refusals.poll(now))

    def _report(self, text: str | None) -> None:
        if text is not None and self.on_refused is not None:
            self.on_refused(text)

    def _dispatch(self, data_type: int, payload: bytes) -> None:
        if data_type == DataType.SCAN:
            try:
                scan = decode_scan(payload)
            except LdmrsProtocolError as exc:
                self.bad_scans += 1
                log.warning("dropped a scan: %s", exc)
                self._report(self.refusals.note(self.clock(), f"scan dropped: {exc}"))
                return
            self.scans += 1
            handler = self.on_scan
            if handler is None:
                self.scans_ignored += 1
                return
            try:
                handler(scan)
            except Exception:  # a bug downstream must not silence the receiver
                self.handler_errors += 1
                log.exception("scan handler failed on scan %d", scan.scan_number)
        elif data_type == DataType.REPLY:
            reply = parse_reply(payload)
            with self._waiters_lock:
                queue = self._waiters.get(reply.cmd)
                waiter = queue.popleft() if queue else None
            if waiter is None:
                self.unexpected_replies += 1
            else:
                waiter._set(reply)
        elif data_type == DataType.ERROR_WARNING:
            self.errors_warnings += 1
            self.last_error_warning = struct.unpack_from("<4H", payload)
            err1, err2, warn1, warn2 = self.last_error_warning
            log.warning("LD-MRS errors 0x%04X 0x%04X warnings 0x%04X 0x%04X", err1, err2, warn1, warn2)

    @property
    def awaiting_replies(self) -> int:
        """Commands sent whose reply has not come."""
        with self._waiters_lock:
            return sum(len(q) for q in self._waiters.values())

    def _fail_waiters(self) -> None:
        with self._waiters_lock:
            waiting = [w for q in self._waiters.values() for w in q]
            self._waiters.clear()
        for w in waiting:
            w._event.set()

    # --- commands ---

    def send_command(self, cmd: int, param: int | None = None, value: int | None = None) -> PendingReply:
        """Send a command; the returned object waits for its reply."""
        if self._sock is None:
            raise LdmrsError("not connected")
        waiter = PendingReply(cmd)
        with self._waiters_lock:
            self._waiters.setdefault(cmd, deque()).append(waiter)
        data = pack_message(DataType.COMMAND, command_payload(cmd, param, value))
        try:
            with self._send_lock:
                self._sock.sendall(data)
                self.bytes_tx += len(data)
        except OSError as exc:
            raise LdmrsError(f"cannot send command 0x{cmd:04X} to LD-MRS: {exc}") from None
        return waiter

    def command(self, cmd: int, param: int | None = None, value: int | None = None,
                timeout: float | None = None) -> Reply:
        """Send a command and check its reply: none in time, or the error bit set, raises LdmrsError."""
        name = Cmd(cmd).name if cmd in Cmd._value2member_map_ else f"0x{cmd:04X}"
        what = name if param is None else f"{name} 0x{param:04X}"
        timeout = self.reply_timeout if timeout is None else timeout
        reply = self.send_command(cmd, param, value).wait(timeout)
        if reply is None:
            reason = self.disconnected or f"no reply within {timeout} s"
            raise LdmrsError(f"LD-MRS {what}: {reason}")
        if not reply.ok:
            raise LdmrsError(f"LD-MRS refused {what}" + (f" = {value}" if value is not None else ""))
        return reply

    def get_status(self) -> ScannerStatus:
        data = self.command(Cmd.GET_STATUS).data
        if len(data) < 12:
            raise LdmrsError(f"GetStatus reply of {len(data)} bytes")
        firmware, fpga, status, _, _, temperature = struct.unpack_from("<6H", data)
        return ScannerStatus(firmware, fpga, status, temperature, data)

    def set_parameter(self, param: int, value: int) -> None:
        self.command(Cmd.SET_PARAMETER, param, value)

    def get_parameter(self, param: int) -> int:
        data = self.command(Cmd.GET_PARAMETER, param).data
        if len(data) < 6:
            raise LdmrsError(f"GetParameter 0x{param:04X} reply of {len(data)} bytes")
        index, value = struct.unpack_from("<HI", data)
        if index != param:
            raise LdmrsError(f"GetParameter 0x{param:04X} answered for parameter 0x{index:04X}")
        return value

    def set_time(self, posix: float) -> None:
        """Set the scanner clock (NTP seconds, then fraction) so its scan timestamps are UTC."""
        ntp = posix_to_ntp(posix)
        self.command(Cmd.SET_NTP_SEC, 0, ntp >> 32)
        self.command(Cmd.SET_NTP_FRAC, 0, ntp & 0xFFFFFFFF)

    def configure(self, cfg: ScannerConfig) -> dict[str, int]:
        """Set every parameter and read it back; returns the read-back values by parameter name.

        Start and end angle are written in the order that keeps start > end at every step.
        """
        params = cfg.parameters()
        current_end = _signed16(self.get_parameter(Param.END_ANGLE))
        if cfg.start_ticks <= current_end:
            order = {Param.END_ANGLE: 0, Param.START_ANGLE: 1}
            params.sort(key=lambda pv: order.get(pv[0], -1))
        readback: dict[str, int] = {}
        for param, value in params:
            self.set_parameter(param, value)
            got = self.get_parameter(param)
            if got != value:
                raise LdmrsError(f"LD-MRS parameter {param.name} reads back {got}, we set {value}")
            readback[param.name] = got
        return readback

    def start_measure(self) -> None:
        self.command(Cmd.START_MEASURE)

    def stop_measure(self, timeout: float | None = None) -> None:
        self.command(Cmd.STOP_MEASURE, timeout=timeout)
