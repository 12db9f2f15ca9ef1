"""LD-MRS simulator: a TCP server on 127.0.0.1 speaking the scanner's exact bytes, scanning the world's
terrain.

``LdmrsDevice`` holds the scanner's logic (parameters, commands, scan generation by ray casting);
``LdmrsSimulator`` serves it on a socket. Each scan sweeps from the start to the end angle in 0.25° steps
(8 ticks) over (start−end)/360 of the rotation period; a beam fired at angle a leaves at
start_time + (end_time − start_time)·(start−a)/(start−end), from where the aircraft is at that instant.
Layers 2 and 3 exist only at angles up to +35° (seed ch. 4.2.3.2). Some beams return a second echo behind a
clutter echo (wire flags transparent|clutter) or a dirt echo on the window (flag dirt), so flag mapping and
point validity are exercised. Test knobs: return fraction, silence after some time, garbage bytes before
messages, messages sent in pieces.
"""

from __future__ import annotations

import functools
import math
import os
import select
import socket
import struct
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from modules.lidar_logger.flags import WIRE_CLUTTER, WIRE_DIRT, WIRE_TRANSPARENT
from modules.lidar_logger.ldmrs_proto import (
    OUTPUT_SCAN,
    Cmd,
    DataType,
    MessageParser,
    Param,
    pack_message,
    parse_command,
    reply_payload,
)
from modules.lidar_logger.ldmrs_scan import (
    NTP_UNIX_OFFSET,
    SCAN_RAIN_LABELED,
    SCAN_REAR_MIRROR,
    TICKS_PER_DEGREE,
    TICKS_PER_ROTATION,
    Scan,
    encode_scan,
    layer_elevation_deg,
    make_points,
    posix_to_ntp,
)
from modules.lidar_logger.sim.background import BackgroundServer
from modules.lidar_logger.sim.world import World

ANGLE_STEP_TICKS = 8
"""0.25°: the constant resolution the seed configures (the simulator uses it whatever the resolution type)."""
TWO_LAYER_ABOVE_TICKS = 35 * TICKS_PER_DEGREE
SCANNER_STATUS_MEASURING = 0x000B
"""motor on | laser on | set frequency reached."""


def _s16(v: int) -> int:
    return v - 0x10000 if v & 0x8000 else v


@dataclass
class LdmrsOptions:
    max_range: float = 200.0
    return_fraction: float = 1.0
    """Share of beams that produce an echo (low-remission ground returns nothing)."""
    clutter_fraction: float = 0.01
    dirt_fraction: float = 0.003
    seed: int = 1
    silent_after: float | None = None
    """Clock seconds after StartMeasure when the scanner stops sending scans (connection stays open)."""
    answer_when_silent: bool = True
    garbage_every: int = 0
    """Put 1-40 junk bytes before every k-th message (0 = never)."""
    split_sends: bool = False
    """Send every message in three pieces a little apart, so the driver sees it across several reads."""
    release_grid: float | None = None
    """Lockstep (docs/lidar_logger.md §8): a scan leaves at the first instant of this grid (clock seconds from 0)
    at or after its end, the MTi-G simulator's sample grid: the sample a driver attaches to it (the newest at or
    before its end) has then been answerable too. None: it leaves as soon as it has ended."""


CATCH_UP_BURST = 4
"""Scans sent in a row before the command socket is read again."""


@functools.lru_cache(maxsize=16)
def _beam_pattern(s_t: int, e_t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    angles = np.arange(s_t, e_t - 1, -ANGLE_STEP_TICKS, dtype=np.int64)
    layers_per = np.where(angles > TWO_LAYER_ABOVE_TICKS, 2, 4)
    angle = np.repeat(angles, layers_per)
    layer = np.arange(len(angle), dtype=np.int64) - np.repeat(np.cumsum(layers_per) - layers_per, layers_per)
    h = np.radians(angle / TICKS_PER_DEGREE)
    el = np.radians(layer_elevation_deg(layer))
    dirs = np.stack((np.cos(el) * np.cos(h), np.cos(el) * np.sin(h), np.sin(el)), axis=-1)
    for a in (angle, layer, dirs):
        a.flags.writeable = False  # shared by every scan of every device
    return angle, layer, dirs


@dataclass
class LdmrsDevice:
    world: World
    options: LdmrsOptions = field(default_factory=LdmrsOptions)
    params: dict[int, int] = field(default_factory=lambda: {
        Param.DATA_OUTPUT_FLAGS: 0xFFEA, Param.START_ANGLE: 1600, Param.END_ANGLE: (-1920) & 0xFFFF,
        Param.SCAN_FREQUENCY: 3200, Param.SYNC_ANGLE_OFFSET: 0, Param.ANGULAR_RESOLUTION_TYPE: 0,
        Param.MOUNTING_X: 0, Param.MOUNTING_Y: 0, Param.MOUNTING_Z: 0, Param.MOUNTING_YAW: 0,
        Param.MOUNTING_PITCH: 0, Param.MOUNTING_ROLL: 0,
    })
    measuring: bool = False
    measure_started_at: float | None = None
    clock_offset: float = 0.0
    """Scanner clock minus true UTC, seconds (0: the scanner is on UTC)."""
    scan_number: int = 0
    commands: list[tuple[float, int, int | None, int | None]] = field(default_factory=list)
    sent_scans: list[Scan] = field(default_factory=list)
    _next_start: float = 0.0
    _ntp_sec: int = 0
    _rng: np.random.Generator = field(init=False)

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.options.seed)

    # --- time ---

    @property
    def period(self) -> float:
        return 256.0 / self.params[Param.SCAN_FREQUENCY]

    @property
    def start_ticks(self) -> int:
        return _s16(self.params[Param.START_ANGLE])

    @property
    def end_ticks(self) -> int:
        return _s16(self.params[Param.END_ANGLE])

    @property
    def sweep(self) -> float:
        return self.period * (self.start_ticks - self.end_ticks) / TICKS_PER_ROTATION

    def scanner_ntp(self, t: float) -> int:
        return posix_to_ntp(self.world.utc(t) + self.clock_offset)

    def silent(self, t: float) -> bool:
        after = self.options.silent_after
        started = self.measure_started_at
        return after is not None and started is not None and t - started >= after

    # --- commands ---

    def handle_command(self, payload: bytes, t: float) -> bytes | None:
        """Reply payload to a command, or None when the scanner stays quiet."""
        cmd = parse_command(payload)
        self.commands.append((t, cmd.cmd, cmd.param, cmd.value))
        if self.silent(t) and not self.options.answer_when_silent:
            return None
        ok = reply_payload(cmd.cmd)
        refuse = reply_payload(cmd.cmd, ok=False)
        if cmd.cmd == Cmd.GET_STATUS:
            status = SCANNER_STATUS_MEASURING if self.measuring else 0x0003
            return ok + struct.pack("<14H", 0x2A31, 0x1C08, status, 0, 0, 0x0ECA, 0x1234, 0x5678, 0x9ABC,
                                    0, 0, 0, 0, 0)
        if cmd.cmd == Cmd.GET_PARAMETER:
            if cmd.param not in self.params:
                return refuse
            return ok + struct.pack("<HI", cmd.param, self.params[cmd.param])
        if cmd.cmd == Cmd.SET_PARAMETER:
            if (self.measuring or cmd.param is None or cmd.value is None
                    or not self._valid(cmd.param, cmd.value)):
                return refuse
            self.params[cmd.param] = cmd.value
            return ok
        if cmd.cmd == Cmd.START_MEASURE:
            if not self.measuring:
                self.measuring = True
                self.measure_started_at = t
                self._next_start = t + 0.5 * self.period
            return ok
        if cmd.cmd == Cmd.STOP_MEASURE:
            self.measuring = False
            return ok
        if cmd.cmd == Cmd.SET_NTP_SEC and cmd.value is not None:
            self._ntp_sec = cmd.value
            return ok
        if cmd.cmd == Cmd.SET_NTP_FRAC and cmd.value is not None:
            set_to = self._ntp_sec - NTP_UNIX_OFFSET + cmd.value / 4294967296.0
            self.clock_offset = set_to - self.world.utc(t)
            return ok
        if cmd.cmd in (Cmd.RESET, Cmd.SAVE_CONFIG, Cmd.RESET_DEFAULTS):
            return ok
        return refuse

    def _valid(self, param: int, value: int) -> bool:
        if param not in self.params:
            return False
        if param == Param.START_ANGLE:
            return -1918 <= _s16(value) <= 1600 and _s16(value) > self.end_ticks
        if param == Param.END_ANGLE:
            return -1920 <= _s16(value) <= 1598 and _s16(value) < self.start_ticks
        if param == Param.SCAN_FREQUENCY:
            return value in (3200, 6400, 12800)
        if param == Param.ANGULAR_RESOLUTION_TYPE:
            return value in (0, 1, 2)
        return 0 <= value <= 0xFFFF

    # --- scans ---

    def due(self, t: float) -> bool:
        """True when the scan in progress has ended by clock time ``t`` (lockstep: and its release instant)."""
        if not self.measuring:
            return False
        end = self._next_start + self.sweep
        grid = self.options.release_grid
        if grid is None:
            return t >= end
        return math.ceil(end / grid - 1e-9) * grid <= t + 1e-6

    def next_due(self) -> float | None:
        return self._next_start + self.sweep if self.measuring else None

    def take_scan(self, send: bool) -> Scan | None:
        """Finish the scan in progress and start the next one; the scan is built when ``send``, scans are
        switched on and the scanner is not silent at its end time. A late caller catches up scan by scan:
        like the real scanner, no rotation is ever skipped, so counts depend on clock time only."""
        start = self._next_start
        self._next_start += self.period
        number = self.scan_number
        self.scan_number = (self.scan_number + 1) & 0xFFFF
        if not send or self.params[Param.DATA_OUTPUT_FLAGS] & OUTPUT_SCAN or self.silent(start + self.sweep):
            return None
        scan = self._build(number, start)
        self.sent_scans.append(scan)
        return scan

    def _beams(self, s_t: int, e_t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every beam of a rotation from ``s_t`` to ``e_t`` ticks: angle, layer, unit direction (scanner frame),
        computed once per angle setting."""
        return _beam_pattern(s_t, e_t)

    def _build(self, number: int, t_start: float) -> Scan:
        s_t, e_t = self.start_ticks, self.end_ticks
        all_angle, all_layer, all_dirs = self._beams(s_t, e_t)
        rng = self._rng
        returns = rng.random(len(all_angle)) < self.options.return_fraction
        angle, layer, dirs = all_angle[returns], all_layer[returns], all_dirs[returns]
        t_beam = t_start + self.sweep * (s_t - angle) / (s_t - e_t)
        origins, world_dirs = self.world.beam_geometry(t_beam, dirs)
        dist = self.world.terrain.ray_cast(origins, world_dirs, self.options.max_range)
        dist_cm = np.rint(np.nan_to_num(dist, nan=0.0) * 100.0)
        keep = np.isfinite(dist) & (dist_cm >= 1) & (dist_cm <= 0xFFFF)
        angle, layer, dist_cm = angle[keep], layer[keep], dist_cm[keep].astype(np.int64)
        n = len(angle)
        u = rng.random(n)
        dirt = u < self.options.dirt_fraction
        p_dirt, p_clutter = self.options.dirt_fraction, self.options.clutter_fraction
        clutter = (u >= p_dirt) & (u < p_dirt + p_clutter)
        extra = dirt | clutter
        k = int(extra.sum())
        extra_dist = np.where(dirt[extra], rng.integers(30, 100, k), rng.integers(300, 2000, k))
        extra_flags = np.where(dirt[extra], WIRE_DIRT, WIRE_TRANSPARENT | WIRE_CLUTTER)
        all_angle = np.concatenate((angle, angle[extra]))
        all_layer = np.concatenate((layer, layer[extra]))
        all_echo = np.concatenate((extra.astype(np.int64), np.zeros(k, dtype=np.int64)))
        all_dist = np.concatenate((dist_cm, extra_dist))
        all_flags = np.concatenate((np.zeros(n, dtype=np.int64), extra_flags))
        width = rng.integers(60, 180, n + k)
        order = np.lexsort((all_echo, all_layer, -all_angle))
        points = make_points(all_layer[order], all_echo[order], all_flags[order], all_angle[order],
                             all_dist[order], width[order])
        flags = SCAN_RAIN_LABELED | (SCAN_REAR_MIRROR if number % 2 else 0)
        return Scan(number, SCANNER_STATUS_MEASURING, 0, self.scanner_ntp(t_start),
                    self.scanner_ntp(t_start + self.sweep), TICKS_PER_ROTATION, s_t, e_t, (0,) * 6, flags,
                    points)


class LdmrsSimulator(BackgroundServer):
    """The device behind a TCP server on ``host:port`` (port 0 picks a free one; see ``.port``)."""

    THREAD_NAME = "ldmrs-sim"

    def __init__(self, world: World, options: LdmrsOptions | None = None, *, host: str = "127.0.0.1",
                 port: int = 0) -> None:
        super().__init__()
        self.world = world
        self.device = LdmrsDevice(world, options or LdmrsOptions())
        self._listener = socket.create_server((host, port))
        self._listener.setblocking(False)
        self.host = host
        self.port = self._listener.getsockname()[1]
        self.connected_at: list[float] = []
        """Clock time of every accepted connection."""
        self.messages_sent = 0
        self._garbage_rng = np.random.default_rng(self.device.options.seed + 1)
        self.bytes_tx = 0
        """Bytes sent on the current connection."""
        self.bytes_rx = 0
        """Bytes received on the current connection and handled (every command they completed answered)."""
        self.lockstep = self.device.options.release_grid is not None
        self._work = threading.Lock()
        """Held while the thread builds and sends scans or answers commands: ``lockstep_busy`` sees the device
        between two passes."""
        subscribe = getattr(world.clock, "subscribe", None)
        self._wake_fd: int | None = subscribe() if self.lockstep and subscribe is not None else None

    def lockstep_busy(self, now: float) -> str:
        """Lockstep: what the scanner has still to send at clock time ``now`` ('' = nothing)."""
        with self._work:
            return "LD-MRS: a scan to send" if self.device.due(now) else ""

    def _release(self) -> None:
        self._listener.close()

    def _send(self, client: socket.socket, data_type: int, payload: bytes, t: float) -> None:
        msg = pack_message(data_type, payload, ntp=self.device.scanner_ntp(t))
        opts = self.device.options
        self.messages_sent += 1
        if opts.garbage_every and self.messages_sent % opts.garbage_every == 0:
            junk = self._garbage_rng.integers(0, 256, int(self._garbage_rng.integers(1, 41)), dtype=np.uint8)
            junk[junk == 0xAF] = 0
            msg = junk.tobytes() + msg
        if opts.split_sends and len(msg) > 3:
            a, b = len(msg) // 3, 2 * len(msg) // 3
            for piece in (msg[:a], msg[a:b], msg[b:]):
                client.sendall(piece)
                self.bytes_tx += len(piece)
                time.sleep(0.0005)
        else:
            client.sendall(msg)
            self.bytes_tx += len(msg)

    def _drain_wake(self) -> None:
        if self._wake_fd is not None:
            try:
                os.read(self._wake_fd, 4096)
            except (BlockingIOError, OSError):
                pass

    def _serve(self) -> None:
        clock = self.world.clock
        client: socket.socket | None = None
        parser = MessageParser()
        wake = [] if self._wake_fd is None else [self._wake_fd]
        while not self._stop.is_set():
            if client is None:
                ready, _, _ = select.select([self._listener, *wake], [], [], 0.05)
                self._drain_wake()
                if self._listener in ready:
                    try:
                        client, _ = self._listener.accept()
                    except BlockingIOError:
                        continue
                    client.setblocking(True)
                    client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    parser = MessageParser()
                    with self._work:
                        self.bytes_tx = self.bytes_rx = 0
                    self.connected_at.append(clock.now())
                now = clock.now()
                with self._work:
                    while self.device.due(now):
                        self.device.take_scan(send=False)
                continue
            due = self.device.next_due()
            now = clock.now()
            timeout = 0.05 if due is None else min(0.05, max(0.0, clock.wall(due - now)))
            try:
                ready, _, _ = select.select([client, *wake], [], [], timeout)
                self._drain_wake()
                with self._work:
                    now = clock.now()
                    burst = 0
                    # scans that ended before the commands below are read; a simulator far behind (a loaded
                    # machine) still reads its commands every few scans, so a StopMeasure is answered while it
                    # catches up
                    while self.device.due(now) and burst < CATCH_UP_BURST:
                        scan = self.device.take_scan(send=True)
                        burst += 1
                        if scan is not None:
                            self._send(client, DataType.SCAN, encode_scan(scan), now)
                    if client in ready:
                        chunk = client.recv(65536)
                        if not chunk:
                            raise ConnectionResetError("client closed")
                        for msg in parser.feed(chunk):
                            if msg.data_type == DataType.COMMAND:
                                reply = self.device.handle_command(msg.payload, clock.now())
                                if reply is not None:
                                    self._send(client, DataType.REPLY, reply, clock.now())
                        self.bytes_rx += len(chunk)
            except OSError:
                client.close()
                client = None
        if client is not None:
            client.close()

