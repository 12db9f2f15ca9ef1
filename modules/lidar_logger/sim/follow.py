"""The lidar simulators flying with the DSP simulator's aircraft (the truth link).

On the aircraft the MTi-G and the LD-MRS measure the real motion. In a launched simulation the real motion is
the DSP simulator's helicopter, so the DSP simulator sends its true state every physics step as a UDP datagram
(``bbcs/contracts/vehicle_truth.py``, ``python -m modules.dsp.sim --truth-udp 127.0.0.1:PORT``) and this
module turns the stream into what the lidar world needs:

- ``FollowClock``: the world's clock *is* the DSP's simulated time, ``lag`` seconds behind the newest datagram
  and advancing at the sender's time scale between datagrams, but never past the newest: every pose and beam
  is interpolated between two real physics steps, so the MTi-G and the LD-MRS always agree, whenever each asks
  (a value extrapolated now and interpolated later would not). When datagrams are late (a loaded machine) the
  clock waits for them. It never runs backwards, stands still at 0 until the first datagram (the MTi-G reports
  no fix: status 0) and stops when the DSP simulator stops.
- ``FollowedFlight``: what ``Flight`` gives the world (position, velocity, attitude at clock times), from the
  received states, converted exactly (WGS84) into the terrain frame.
- ``TruthReceiver``: the UDP socket and its thread; invalid datagrams are counted and dropped.

Conventions: the DSP's attitude is aerospace (body x forward, y right, z down; positive pitch nose up,
heading clockwise from north); the MTi-G's body frame is x forward, y left, z up, so R_NWU←FLU =
T · R_NED←FRD · T with T = diag(1, −1, −1), i.e. MTi-G Euler = (roll, −pitch, −heading).
"""

from __future__ import annotations

import math
import socket
import threading
import time
from collections.abc import Callable

import msgspec
import numpy as np

from bbcs.contracts.vehicle_truth import VehicleTruth, decode_truth
from modules.lidar_logger.clock import ScaledClock
from modules.lidar_logger.geodesy import ecef_from_enu, ecef_from_nwu, euler_to_matrix, lla_to_ecef

DEFAULT_LAG_S = 0.25
"""Simulated seconds the clock stays behind the newest datagram (12 physics steps at 50 Hz)."""
HISTORY = 6000
"""States kept (two minutes of simulated time at 50 Hz): the scanner never looks further back than a scan."""
FLU_FROM_FRD = np.diag([1.0, -1.0, -1.0])


class FollowClock(ScaledClock):
    """The DSP simulator's time, as ``Clock`` (modules/lidar_logger/clock.py) wants it: a scaled clock whose scale
    and origin follow the simulator's truth datagrams (its sleeps and waits are ScaledClock's)."""

    def __init__(self, lag: float = DEFAULT_LAG_S) -> None:
        super().__init__(1.0)
        self.lag = lag
        self._lock = threading.Lock()
        self._newest: float | None = None
        self._newest_mono = 0.0
        self._last = 0.0

    def on_truth(self, time_s: float, time_scale: float) -> None:
        with self._lock:
            if self._newest is None or time_s > self._newest:
                self._newest, self._newest_mono, self.scale = time_s, time.monotonic(), time_scale

    def now(self) -> float:
        with self._lock:
            if self._newest is None:
                return self._last
            ahead = (time.monotonic() - self._newest_mono) * self.scale
            self._last = max(self._last, min(self._newest, self._newest - self.lag + ahead))
            return self._last


class FollowedFlight:
    """Position, velocity and R_terrainENU←body at clock times, interpolated between received states.

    The terrain frame is anchored at ``origin_lla``, or (None) at the DSP's home from the first state, when
    ``on_anchor`` is called with it (the world anchors its terrain there too).
    """

    def __init__(self, origin_lla: tuple[float, float, float] | None = None,
                 on_anchor: Callable[[tuple[float, float, float]], None] | None = None) -> None:
        self._lock = threading.Lock()
        self.on_anchor = on_anchor
        self.origin_lla: tuple[float, float, float] | None = None
        self._n = 0
        self._t = np.empty(2 * HISTORY)
        self._rows = np.empty((2 * HISTORY, 18))  # pos 3, vel 3, attitude 3, R_terrain←NWU 9
        self._origin_ecef = np.zeros(3)
        self._terrain_from_ecef: np.ndarray | None = None
        if origin_lla is not None:
            self._anchor(origin_lla)

    def _anchor(self, origin_lla: tuple[float, float, float]) -> None:
        self.origin_lla = tuple(float(v) for v in origin_lla)  # type: ignore[assignment]
        self._origin_ecef = lla_to_ecef(np.array(origin_lla))
        self._terrain_from_ecef = ecef_from_enu(origin_lla[0], origin_lla[1]).T

    @property
    def samples(self) -> int:
        return self._n

    def add(self, truth: VehicleTruth) -> None:
        """One received state, in time order (one not newer than the newest is ignored)."""
        anchored = None
        with self._lock:
            n = self._n
            if n and truth.time_s <= self._t[n - 1]:
                return
            if self._terrain_from_ecef is None:
                self._anchor(truth.home)
                anchored = self.origin_lla
            assert self._terrain_from_ecef is not None
            lla = np.array([truth.lat, truth.lon, truth.alt])
            pos = self._terrain_from_ecef @ (lla_to_ecef(lla) - self._origin_ecef)
            vn, ve, vu = truth.vel_neu
            vel = self._terrain_from_ecef @ (ecef_from_enu(truth.lat, truth.lon) @ np.array([ve, vn, vu]))
            heading = truth.heading
            if n:
                prev = self._rows[n - 1, 8]
                heading = prev + (heading - prev + 180.0) % 360.0 - 180.0
            frame = self._terrain_from_ecef @ ecef_from_nwu(truth.lat, truth.lon)
            if n == len(self._t):  # full: keep the newest HISTORY - 1 (readers copy what they use, under the lock)
                self._t[:HISTORY - 1] = self._t[n - HISTORY + 1:]
                self._rows[:HISTORY - 1] = self._rows[n - HISTORY + 1:]
                n = HISTORY - 1
            self._t[n] = truth.time_s
            self._rows[n, 0:3], self._rows[n, 3:6] = pos, vel
            self._rows[n, 6:9] = truth.roll, truth.pitch, heading
            self._rows[n, 9:18] = frame.ravel()
            self._n = n + 1
        if anchored is not None and self.on_anchor is not None:
            self.on_anchor(anchored)

    def state(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """As ``Flight.state``: position (N,3), velocity (N,3), R_terrainENU←body (N,3,3) at clock times ``t``.

        Between two states: linear in position, velocity and attitude angles; after the newest: along its
        velocity, attitude held; before the oldest kept: the oldest. Before any state: at the origin, level.
        """
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        with self._lock:
            n = self._n
            if not n:
                return np.zeros((len(t), 3)), np.zeros((len(t), 3)), np.tile(np.eye(3), (len(t), 1, 1))
            ts = self._t[:n]
            tc = np.clip(t, ts[0], ts[-1])
            i = np.clip(np.searchsorted(ts, tc, side="right") - 1, 0, n - 1)
            j = np.minimum(i + 1, n - 1)
            ti, tj = ts[i], ts[j]
            a, b = self._rows[i], self._rows[j]
        span = tj - ti
        w = np.where(span > 0, (tc - ti) / np.where(span > 0, span, 1.0), 0.0)[:, None]
        row = a + (b - a) * w
        pos = row[:, 0:3] + b[:, 3:6] * (t - tc)[:, None]
        r_nwu_flu = FLU_FROM_FRD @ euler_to_matrix(row[:, 6:9]) @ FLU_FROM_FRD
        return pos, row[:, 3:6], a[:, 9:18].reshape(-1, 3, 3) @ r_nwu_flu


class TruthReceiver:
    """Binds ``127.0.0.1:port`` (0 = any, see ``.port``) and feeds every valid datagram to the clock and flight."""

    def __init__(self, clock: FollowClock, flight: FollowedFlight, port: int = 0, host: str = "127.0.0.1") -> None:
        self.clock = clock
        self.flight = flight
        self.received = 0
        self.invalid = 0
        self.lost = 0
        self.first = threading.Event()
        self._last_seq: int | None = None
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # a second of datagrams at any time scale: this thread shares the GIL with the ray casting
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self._sock.bind((host, port))
        self._sock.settimeout(0.1)
        self.port = self._sock.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="truth-rx", daemon=True)

    def start(self) -> TruthReceiver:
        self._thread.start()
        return self

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                data = self._sock.recv(2048)
            except TimeoutError:
                continue
            except OSError:
                return
            try:
                truth = decode_truth(data)
            except (msgspec.DecodeError, msgspec.ValidationError):
                self.invalid += 1
                continue
            if not all(map(math.isfinite, (truth.lat, truth.lon, truth.alt, *truth.vel_neu))):
                self.invalid += 1
                continue
            if self._last_seq is not None and truth.seq > self._last_seq + 1:
                self.lost += truth.seq - self._last_seq - 1
            self._last_seq = truth.seq
            self.flight.add(truth)
            self.clock.on_truth(truth.time_s, truth.time_scale)
            self.received += 1
            self.first.set()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._sock.close()

    def __enter__(self) -> TruthReceiver:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
