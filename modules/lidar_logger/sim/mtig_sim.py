"""MTi-G simulator on a pseudo-terminal, speaking the exact Xbus bytes of a real device.

``MTiGDevice`` is the device's logic (pure: frames in, frames out, time given); ``MTiGSimulator`` puts it on a
pty whose slave path the driver opens like ``/dev/ttyUSB0``. Like the real unit it powers up in measurement
state streaming its default output (calibrated data + quaternion + sample counter at 100 Hz), so a driver
must find its GoToConfig acknowledgement among MTData frames. Configuration messages are acknowledged (MID+1),
unknown ones answered with Error 0x04, ReqData with MTData of the configured layout, and the status byte
follows the world's timeline 0 → 5 → 7.
"""

from __future__ import annotations

import math
import os
import select
import struct
import threading
import tty
from dataclasses import dataclass, field

from modules.lidar_logger.mtdata import (
    MODE_CALIB,
    MODE_ORIENT,
    SET_TS_SAMPLE_COUNTER,
    MTDataError,
    encode_pose_payload,
    layout,
)
from modules.lidar_logger.sim.background import BackgroundServer
from modules.lidar_logger.sim.world import World
from modules.lidar_logger.xbus import MID, Frame, FrameParser, ack_of, build_frame

DEFAULT_MODE = MODE_CALIB | MODE_ORIENT
DEFAULT_SETTINGS = SET_TS_SAMPLE_COUNTER
DEFAULT_DEVICE_ID = 0x00500123
"""An MTi-G device id (type nibble 0x005)."""
ERR_INVALID_MESSAGE = 0x04
ERR_INVALID_PARAMETER = 0x21
TIME_EPS_S = 1e-6
"""A sample instant and a clock time closer than this are the same (sums of 0.02 s physics steps drift)."""


@dataclass
class MTiGDevice:
    world: World
    device_id: int = DEFAULT_DEVICE_ID
    state: str = "measurement"
    mode: int = DEFAULT_MODE
    settings: int = DEFAULT_SETTINGS
    skip_factor: int = 0
    period: int = 1152
    """Sample period in 1/115200 s (1152 = 100 Hz)."""
    lever_arm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scenario: int = 1
    sample_counter: int = 0
    received: list[tuple[float, int, bytes]] = field(default_factory=list)
    """(clock time, MID, data) of every message received."""
    poses_sent: list[tuple[float, object]] = field(default_factory=list)
    """(clock time, Pose) of every MTData answering a ReqData."""
    sample_period: float | None = None
    """Lockstep (docs/lidar_logger.md §8): ReqData is answered with the device's *next* sample of a series every
    ``sample_period`` clock seconds (on a grid from clock 0), held until the clock reaches it: the requests are
    paced by simulated time, so the samples a driver gets do not depend on when its requests came on the wall.
    None: answered at once with the pose at the clock's time (a real device's newest sample)."""
    pending: int = 0
    """Lockstep: ReqData received and not yet answered."""
    next_index: int | None = None
    """Lockstep: grid index of the next sample to answer (set by the first ReqData)."""
    def _mtdata(self, t: float, record: bool) -> bytes:
        pose = self.world.true_pose(t)
        payload = encode_pose_payload(pose, self.mode, self.settings, self.sample_counter)
        self.sample_counter = (self.sample_counter + 1) & 0xFFFF
        if record:
            self.poses_sent.append((t, pose))
        return build_frame(MID.MTDATA, payload)

    def handle(self, frame: Frame, t: float) -> list[bytes]:
        """Answer one frame received at clock time ``t``."""
        mid, data = frame.mid, frame.data
        self.received.append((t, mid, data))

        def ack(payload: bytes = b"") -> list[bytes]:
            return [build_frame(ack_of(mid), payload)]

        def error(code: int) -> list[bytes]:
            return [build_frame(MID.ERROR, bytes((code,)))]

        if mid == MID.GOTO_CONFIG:
            self.state = "config"
            return ack()
        if mid == MID.GOTO_MEASUREMENT:
            self.state = "measurement"
            return ack()
        if mid == MID.REQ_DATA:
            if self.sample_period is not None:
                if self.next_index is None:
                    self.next_index = max(0, math.ceil(t / self.sample_period - TIME_EPS_S))
                self.pending += 1
                return []
            return [self._mtdata(t, record=True)]
        if mid == MID.REQ_DID:
            return ack(struct.pack(">I", self.device_id))
        if self.state != "config":
            return error(ERR_INVALID_MESSAGE)
        if mid == MID.SET_OUTPUT_MODE:
            if not data:
                return ack(struct.pack(">H", self.mode))
            if len(data) != 2:
                return error(ERR_INVALID_PARAMETER)
            self.mode = struct.unpack(">H", data)[0]
            return ack()
        if mid == MID.SET_OUTPUT_SETTINGS:
            if not data:
                return ack(struct.pack(">I", self.settings))
            if len(data) != 4:
                return error(ERR_INVALID_PARAMETER)
            self.settings = struct.unpack(">I", data)[0]
            return ack()
        if mid == MID.SET_OUTPUT_SKIP_FACTOR:
            if len(data) != 2:
                return error(ERR_INVALID_PARAMETER)
            self.skip_factor = struct.unpack(">H", data)[0]
            return ack()
        if mid == MID.SET_PERIOD:
            if len(data) != 2:
                return error(ERR_INVALID_PARAMETER)
            self.period = struct.unpack(">H", data)[0]
            return ack()
        if mid == MID.SET_GPS_LEVER_ARM:
            if len(data) != 12:
                return error(ERR_INVALID_PARAMETER)
            self.lever_arm = struct.unpack(">3f", data)
            return ack()
        if mid == MID.SET_SCENARIO:
            if len(data) != 2:
                return error(ERR_INVALID_PARAMETER)
            self.scenario = struct.unpack(">H", data)[0]
            return ack()
        if mid == MID.REQ_DATA_LENGTH:
            try:
                length = layout(self.mode, self.settings).length
                return [build_frame(MID.DATA_LENGTH, struct.pack(">H", length))]
            except MTDataError:
                return error(ERR_INVALID_PARAMETER)
        return error(ERR_INVALID_MESSAGE)

    def stream_interval(self) -> float | None:
        """Clock seconds between unrequested MTData frames; None when the device only answers ReqData."""
        if self.state != "measurement" or self.skip_factor == 0xFFFF:
            return None
        return self.period * (self.skip_factor + 1) / 115200.0

    def stream(self, t: float) -> bytes:
        return self._mtdata(t, record=False)

    def answerable(self, t: float) -> bool:
        """Lockstep: a held ReqData whose sample instant the clock (``t``) has reached."""
        return (self.sample_period is not None and self.pending > 0 and self.next_index is not None
                and self.next_index * self.sample_period <= t + TIME_EPS_S)

    def answer_held(self) -> bytes:
        """Lockstep: the MTData of the next sample (``answerable`` first)."""
        assert self.sample_period is not None and self.next_index is not None
        frame = self._mtdata(self.next_index * self.sample_period, record=True)
        self.next_index += 1
        self.pending -= 1
        return frame

    def first_status_time(self, status: int) -> float | None:
        """Clock time of the first ReqData answered with this status byte."""
        for t, pose in self.poses_sent:
            if pose.status == status:  # type: ignore[attr-defined]
                return t
        return None


class MTiGSimulator(BackgroundServer):
    """The device on a pty, served by a thread. ``port`` is the path a driver opens.

    In a lockstep simulation (the device's ``sample_period`` set) it also counts the bytes it wrote and the bytes
    it read and handled (``bytes_tx``, ``bytes_rx``), says what it still has to do at a clock time
    (``lockstep_busy``), wakes when the world's clock moves (``world.clock.subscribe()``, ``sim/lockstep.py``) and
    stays silent until the driver has written to it (a driver's open flushes what the pty held: the power-up stream
    would be written and never read)."""

    THREAD_NAME = "mtig-sim"

    def __init__(self, world: World, **device_kwargs) -> None:
        super().__init__()
        self.world = world
        self.device = MTiGDevice(world, **device_kwargs)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)
        self.parser = FrameParser()
        self.dropped_writes = 0
        self.bytes_tx = 0
        self.bytes_rx = 0
        self.lockstep = self.device.sample_period is not None
        self._work = threading.Lock()
        """Held while the thread reads, answers or streams: ``lockstep_busy`` sees the device between two passes."""
        subscribe = getattr(world.clock, "subscribe", None)
        self._wake_fd: int | None = subscribe() if self.lockstep and subscribe is not None else None
        self._next_stream: float | None = None

    def _release(self) -> None:
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def inject(self, data: bytes) -> None:
        """Put raw bytes on the line (line noise, a corrupt frame) as if the device had sent them."""
        self._write(data)

    def _write(self, data: bytes) -> None:
        try:
            self.bytes_tx += os.write(self._master, data)
        except BlockingIOError:
            self.dropped_writes += 1  # nobody reads the port: a real UART would overrun too

    def lockstep_busy(self, now: float) -> str:
        """Lockstep: what the device has still to write at clock time ``now`` ('' = nothing)."""
        with self._work:
            if self.device.answerable(now):
                return "MTi-G: a ReqData to answer"
            if self._streaming() and self._next_stream is not None and now >= self._next_stream:
                return "MTi-G: a sample to stream"
            return ""

    def _streaming(self) -> bool:
        return self.device.stream_interval() is not None and (not self.lockstep or self.bytes_rx > 0)

    def _serve(self) -> None:
        clock = self.world.clock
        fds = [self._master] if self._wake_fd is None else [self._master, self._wake_fd]
        while not self._stop.is_set():
            interval = self.device.stream_interval()
            now = clock.now()
            if interval is None or not self._streaming():
                self._next_stream = None
                timeout = 0.05
            else:
                if self._next_stream is None:
                    self._next_stream = now
                timeout = min(0.05, max(0.0, clock.wall(self._next_stream - now)))
            if self.device.answerable(now):
                timeout = 0.0
            ready, _, _ = select.select(fds, [], [], timeout)
            if self._wake_fd is not None and self._wake_fd in ready:
                try:
                    os.read(self._wake_fd, 4096)
                except (BlockingIOError, OSError):
                    pass
            with self._work:
                if self._master in ready:
                    try:
                        chunk = os.read(self._master, 4096)
                    except (BlockingIOError, OSError):
                        chunk = b""
                    for frame in self.parser.feed(chunk):
                        for reply in self.device.handle(frame, clock.now()):
                            self._write(reply)
                    self.bytes_rx += len(chunk)
                while self.device.answerable(clock.now()):
                    self._write(self.device.answer_held())
                if self._next_stream is not None and self._streaming():
                    now = clock.now()
                    if now >= self._next_stream:
                        self._write(self.device.stream(now))
                        self._next_stream += interval
                        if self._next_stream < now:  # fell behind: skip samples rather than send a burst
                            self._next_stream = now + interval
