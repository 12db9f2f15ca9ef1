"""The PC end of the DSP serial link: one port, one reader thread, acknowledged commands with retries.

Any pyserial URL works (``/dev/ttyUSB0``, a pty path, ``socket://127.0.0.1:PORT``, ``loop://``), so the same
code drives the real DSP and the simulator. Commands are stop-and-wait (docs/dsp_protocol.md §3): one
outstanding command, resent with the same sequence number until acknowledged, at most ``retries`` times.
Waiting happens on a Condition with its lock held (the seed's §5.2.1.1 bug is impossible by construction).
"""

from __future__ import annotations

import errno
import fcntl
import logging
import random
import struct
import termios
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING

import serial

from bbcs.clock import WALL, Clock
from bbcs.contracts import dsp as p
from bbcs.contracts.dsp import LinkStats
from bbcs.serial_io import write_all
from modules.dsp.codec import DSP_TO_PC_LENGTHS, DspDecodeError, decode, encode_payload
from modules.dsp.errors import DspLinkError, DspPreempted, DspRejected, DspTimeout
from modules.dsp.framing import MAX_FRAME, Frame, FrameParser, build_frame
from modules.dsp.refusals import Refusal

if TYPE_CHECKING:
    from modules.dsp.config import DspConfig

log = logging.getLogger(__name__)


def lockstep_link(robot: str) -> str:
    """The DSP line's name as a lockstep device link (``bbcs.lockstep.wire_counts``), the same at both ends: the
    DSP module reports its end, the robot's simulator checks it, or pairs its own with it as a fleet's follower."""
    return f"dsp/{robot}"

WRITE_TIMEOUT_S = 2.0
"""A frame the port takes no byte of for this long fails the link (``bbcs.serial_io.write_all``)."""


_COUNTERS = tuple(f for f in LinkStats.__struct_fields__ if f not in (
    "frames_ok", "bytes_rx", "bytes_discarded", "bad_crc", "unknown_id", "bad_length", "oversize",
    "truncated", "last_refused"))


def open_port(url: str, baudrate: int, *, read_timeout: float = 0.02,
              exclusive: bool = True) -> serial.Serial:
    """Open ``url`` with pyserial; DspLinkError saying plainly when it is missing, busy or not permitted."""
    try:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=read_timeout, write_timeout=WRITE_TIMEOUT_S,
                                     exclusive=exclusive)
    except serial.SerialException as exc:
        code = exc.errno if isinstance(exc.errno, int) else (exc.args[0] if exc.args and isinstance(
            exc.args[0], int) else None)
        text = str(exc)
        if code == errno.ENOENT or "No such file" in text:
            why = "the port does not exist (unplugged? wrong name?)"
        elif code == errno.EBUSY or "exclusively lock" in text:
            why = "the port is busy: another process has it open"
        elif code == errno.EACCES or "Permission denied" in text:
            why = "permission denied (is the user in the 'dialout' group?)"
        elif "Connection refused" in text:
            why = "nothing listens at that address"
        else:
            why = text
        raise DspLinkError(f"cannot open DSP port {url}: {why}") from exc
    except (ValueError, OSError) as exc:
        raise DspLinkError(f"cannot open DSP port {url}: {exc}") from exc


class DspLink:
    """An open link to the DSP. Thread-safe: any thread may ``send``; callbacks run on the reader thread."""

    def __init__(self, url: str, baudrate: int = 921_600, *, ack_timeout: float = 0.25, retries: int = 3,
                 on_telemetry: Callable[[p.Telemetry], None] | None = None,
                 on_error: Callable[[p.DspError], None] | None = None,
                 on_refused: Callable[[Refusal], None] | None = None,
                 read_timeout: float = 0.02, exclusive: bool = True, clock: Clock = WALL) -> None:
        if ack_timeout <= 0 or retries < 0:
            raise ValueError("ack_timeout must be > 0 and retries >= 0")
        self.url = url
        self.baudrate = baudrate
        self.ack_timeout = ack_timeout
        self.retries = retries
        self.clock = clock
        """What the ACK timeout is measured on: the robot's clock (simulated time in lockstep, bbcs/clock.py)."""
        self.bytes_handled = 0
        """Bytes read from the port whose frames were all dispatched (a lockstep simulator compares it)."""
        self.on_telemetry = on_telemetry
        self.on_error = on_error
        self.on_refused = on_refused
        """Called (on the reader thread) for each telemetry frame refused: malformed, or a field out of range."""
        self._last_refused = ""
        self._serial = open_port(url, baudrate, read_timeout=read_timeout, exclusive=exclusive)
        self._parser = FrameParser(DSP_TO_PC_LENGTHS)
        self._idle_s = max(0.05, 2 * MAX_FRAME * 10 / baudrate)
        self._cond = threading.Condition()
        self._send_lock = threading.Lock()
        self._write_lock = threading.Lock()
        self._pending: tuple[int, int] | None = None
        self._pending_ack: p.Ack | None = None
        self._failure: DspLinkError | None = None
        self._closing = False
        self._closed = False
        self._seq = random.randrange(256)
        self._abort_generation = 0
        """Counts ABORTs announced (:meth:`preempt`): a waypoint list or a command waiting for its ACK stops."""
        self._last_dsp_seq: int | None = None
        self._latest: p.Telemetry | None = None
        self._counts = dict.fromkeys(_COUNTERS, 0)
        self._counts_lock = threading.Lock()
        self._reader = threading.Thread(target=self._read_loop, name=f"dsp-reader {url}", daemon=True)
        self._reader.start()

    # --- lifecycle ---------------------------------------------------------------------------------------

    def __enter__(self) -> DspLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the reader and close the port; safe to call any number of times."""
        with self._cond:
            if self._closed:
                return
            self._closed = self._closing = True
            self._cond.notify_all()
        cancel = getattr(self._serial, "cancel_read", None)
        if cancel is not None:
            try:
                cancel()
            except Exception:  # the port may already be gone; closing must still finish
                pass
        if self._reader is not threading.current_thread():
            self._reader.join(timeout=2.0)
        try:
            self._serial.close()
        except Exception as exc:
            log.debug("closing %s: %s", self.url, exc)

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def failure(self) -> DspLinkError | None:
        """Why the link stopped working (port vanished...), or None while it works."""
        return self._failure

    # --- commands ------------------------------------------------------------------------------------------

    def preempt(self) -> None:
        """An ABORT is waiting: a command other than ABORT now waiting for its acknowledgement stops waiting
        (DspPreempted), so the ABORT goes on the line at once instead of after that command's retries (up to
        ``(retries + 1) * ack_timeout`` with a silent DSP; the safety monitor's bound is 100 ms)."""
        with self._cond:
            self._abort_generation += 1
            self._cond.notify_all()

    def send(self, cmd: p.Command, *, timeout: float | None = None, retries: int | None = None) -> p.Ack:
        """Send ``cmd`` and wait for its ACK. DspValueError (nothing sent), DspTimeout, DspRejected,
        DspPreempted (an ABORT is waiting: :meth:`preempt`)."""
        payload = encode_payload(cmd)  # refuses out-of-range values before anything is sent
        name = type(cmd).__name__
        timeout = self.ack_timeout if timeout is None else timeout
        retries = self.retries if retries is None else retries
        msg_id = int(cmd.MSG_ID)
        preemptible = not isinstance(cmd, p.Abort)
        with self._send_lock:
            generation = self._abort_generation
            self._raise_if_unusable(name)
            self._seq = seq = (self._seq + 1) & 0xFF
            frame = build_frame(msg_id, seq, payload)
            with self._cond:
                self._pending, self._pending_ack = (msg_id, seq), None
            try:
                ack = None
                for attempt in range(retries + 1):
                    if attempt:
                        self._count("retries")
                    self._write(frame)
                    with self._cond:
                        self.clock.wait_for(self._cond, lambda: self._pending_ack is not None or self._closing
                                            or self._failure is not None
                                            or (preemptible and self._abort_generation != generation), timeout)
                        ack = self._pending_ack
                    if ack is not None:
                        break
                    self._raise_if_unusable(name)
                    if preemptible and self._abort_generation != generation:
                        self._count("preempted")
                        raise DspPreempted(name, seq)
                if ack is None:
                    self._count("timeouts")
                    raise DspTimeout(name, seq, retries + 1, timeout, self.url)
            finally:
                with self._cond:
                    self._pending = self._pending_ack = None
        if ack.status != 0:
            self._count("nacks")
            raise DspRejected(name, ack.status)
        self._count("commands_acked")
        return ack

    def send_all(self, cmds: Iterable[p.Command]) -> list[p.Ack]:
        """Send commands in order, each acknowledged before the next; the first failure stops the rest."""
        return [self.send(cmd) for cmd in cmds]

    def send_waypoints(self, points: Sequence[p.AddWaypoint]) -> int:
        """Queue waypoints on the DSP in order; returns how many were acknowledged before an ``abort()`` stopped
        them (the one on the line when it came may have reached the DSP too: the abort empties its queue either way).

        All points are range-checked first: if one is bad, none is sent (SPEC: no datum affected by an
        error is sent).
        """
        for point in points:
            p.check(point)
        generation = self._abort_generation
        sent = 0
        for point in points:
            if self._abort_generation != generation:
                break
            try:
                self.send(point)
            except DspPreempted:  # the abort took the line from this point (which the DSP may have queued)
                break
            sent += 1
        return sent

    def abort(self) -> p.Ack:
        """Flush: stop any waypoint list being sent from this PC, then empty the DSP's queue (ABORT)."""
        self.preempt()
        return self.send(p.Abort())

    def ping(self, *, timeout: float | None = None, retries: int | None = None) -> p.Ack:
        return self.send(p.Ping(), timeout=timeout, retries=retries)

    # --- state -------------------------------------------------------------------------------------------

    @property
    def latest_telemetry(self) -> p.Telemetry | None:
        return self._latest

    def stats(self) -> LinkStats:
        st = self._parser.stats
        with self._counts_lock:
            counts = dict(self._counts)
        return LinkStats(frames_ok=st.frames, bytes_rx=st.bytes_in, bytes_discarded=st.bytes_discarded,
                         bad_crc=st.bad_crc, unknown_id=st.unknown_id, bad_length=st.bad_length,
                         oversize=st.oversize, truncated=st.truncated, last_refused=self._last_refused, **counts)

    # --- internals ---------------------------------------------------------------------------------------

    def _count(self, name: str, n: int = 1) -> None:
        with self._counts_lock:
            self._counts[name] += n

    def _raise_if_unusable(self, name: str) -> None:
        if self._failure is not None:
            raise DspLinkError(f"cannot send {name}: {self._failure}")
        if self._closing:
            raise DspLinkError(f"cannot send {name}: the link to {self.url} is closed")

    def _write(self, frame: bytes) -> None:
        try:
            with self._write_lock:
                write_all(self._serial, frame, WRITE_TIMEOUT_S, lambda n: self._count("bytes_tx", n))
        except (serial.SerialException, OSError) as exc:
            raise DspLinkError(f"writing to DSP port {self.url} failed: {exc}") from exc
        self._count("frames_sent")

    def _read_loop(self) -> None:
        ser = self._serial
        parser = self._parser
        last_rx = time.monotonic()
        while not self._closing:
            try:
                waiting = bytes_waiting(ser)
                data = ser.read(waiting if waiting > 0 else 1)
            except Exception as exc:  # any failure of the port ends the link, and says why
                if not self._closing:
                    with self._cond:
                        self._failure = DspLinkError(f"DSP port {self.url} failed: {exc}")
                        self._cond.notify_all()
                    log.error("%s", self._failure)
                return
            if data:
                last_rx = time.monotonic()
                frames = parser.feed(data)
            elif parser.buffered and time.monotonic() - last_rx >= self._idle_s:
                frames = parser.flush_pending()
            else:
                continue
            for frame in frames:
                self._dispatch(frame)
            self.bytes_handled = parser.stats.bytes_in

    def _dispatch(self, frame: Frame) -> None:
        if self._last_dsp_seq is not None:
            self._count("dsp_frames_lost", (frame.seq - self._last_dsp_seq - 1) & 0xFF)
        self._last_dsp_seq = frame.seq
        try:
            msg = decode(frame)
        except DspDecodeError as exc:
            self._count("decode_errors")
            log.debug("dropped undecodable frame: %s", exc)
            if frame.msg_id == p.MsgId.TELEMETRY:
                self._refuse(Refusal("frame", str(exc)))
            return
        if isinstance(msg, p.Ack):
            with self._cond:
                if self._pending == (msg.acked_id, msg.acked_seq) and self._pending_ack is None:
                    self._pending_ack = msg
                    self._cond.notify_all()
                    return
            self._count("stray_acks")
        elif isinstance(msg, p.Telemetry):
            try:  # every field against the range its type declares (bbcs/contracts/dsp.py): one rule for all
                p.check(msg)
            except p.DspValueError as exc:
                self._refuse(Refusal(exc.field or "frame", str(exc)))
                return
            self._latest = msg
            self._count("telemetry_frames")
            self._callback(self.on_telemetry, msg)
        elif isinstance(msg, p.DspError):
            self._count("dsp_errors")
            self._callback(self.on_error, msg)

    def _refuse(self, refusal: Refusal) -> None:
        """A telemetry frame that passed the CRC but cannot be used: dropped, counted, handed to ``on_refused``."""
        self._count("telemetry_refused")
        self._last_refused = refusal.detail
        self._callback(self.on_refused, refusal)

    def _callback(self, fn: Callable | None, msg: object) -> None:
        if fn is None:
            return
        try:
            fn(msg)
        except Exception:  # a faulty consumer must not stop the reader
            self._count("callback_errors")
            log.exception("DSP %s callback failed", type(msg).__name__)


def bytes_waiting(ser: serial.SerialBase) -> int:
    """Bytes ready to read on ``ser``.

    Why not ``in_waiting`` alone: on a ``socket://`` port (a simulator's end) pyserial answers 0 or 1 (one select),
    so the reader took the stream a byte at a time, two system calls and a parser call per byte; on a loaded
    machine it fell behind the simulator's telemetry and the ACKs queued behind it came after the 4 x 0.25 s window.
    The socket's own count (FIONREAD) is exact; a serial device's ``in_waiting`` already is."""
    sock = getattr(ser, "_socket", None)
    if sock is not None:
        return struct.unpack("i", fcntl.ioctl(sock.fileno(), termios.FIONREAD, b"\0\0\0\0"))[0]
    return ser.in_waiting


# --- start-up sequence (SPEC §3) ---------------------------------------------------------------------------


def startup_commands(conf: DspConfig) -> list[p.Command]:
    """SPEC §3's start-up sequence, in its exact order."""
    return [
        p.SetSpeed(speed=0.0),  # 1. safety first
        p.SetTelemetryMask(mask=conf.telemetry_mask),  # 2.
        p.SetStateTransmission(enable=True, period_ms=conf.telemetry_period_ms),
        p.ClearError(),
        p.SetTracking(enable=False),
        p.InvalidatePath(),
        p.SetHelicopterType(heli_type=conf.heli_type),  # 3.
        *conf.pid_groups,  # 4. every controller parameter group, in file order
    ]


def startup(link: DspLink, conf: DspConfig) -> list[p.Ack]:
    """Run the start-up sequence; the first timeout or refusal stops it and is raised (naming the command)."""
    commands = startup_commands(conf)
    for cmd in commands:
        p.check(cmd)  # a bad .conf value stops start-up before anything is sent
    return link.send_all(commands)


def open_link(conf: DspConfig, **kwargs: object) -> DspLink:
    """A link on the configured port, baud, ack timeout and retries."""
    return DspLink(conf.port, conf.baudrate, ack_timeout=conf.ack_timeout_s, retries=conf.retries,
                   **kwargs)  # type: ignore[arg-type]


__all__ = ["DspLink", "DspLinkError", "DspRejected", "DspTimeout", "open_link", "open_port",
           "startup", "startup_commands"]
