"""Line faults for the simulator, the tests and the benchmark: corrupted bytes, lost bytes, garbage bursts.

Bursts can carry a *false header* — ``A5 5A`` followed by a known id and the length valid for it — which is
the nastiest case for a receiver: it claims the bytes of the real frame behind it. A receiver that discards a
whole claimed frame on a bad CRC loses the real one; ours must not (docs/dsp_protocol.md §6).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field

import msgspec
import numpy as np

from bbcs.contracts import dsp as p
from modules.dsp.framing import SYNC


@dataclass
class FaultCounts:
    bytes_corrupted: int = 0
    bytes_dropped: int = 0
    garbage_bursts: int = 0
    garbage_bytes: int = 0
    false_headers: int = 0


@dataclass
class FaultInjector:
    """Applies faults to bytes on their way out. Rates are probabilities; ``seed`` makes runs repeatable.

    ``corrupt``: per byte, the byte is XORed with a random non-zero value (so it really changes).
    ``drop``: per byte, the byte is lost. ``garbage``: per call, a burst of 1..``burst_max`` random bytes is
    inserted before the data; half the bursts start with a false header for an id in ``false_ids``.
    """

    corrupt: float = 0.0
    drop: float = 0.0
    garbage: float = 0.0
    burst_max: int = 48
    seed: int | None = None
    false_ids: Mapping[int, int] = field(default_factory=dict)  # id -> payload length for false headers
    counts: FaultCounts = field(default_factory=FaultCounts)

    def __post_init__(self) -> None:
        for name in ("corrupt", "drop", "garbage"):
            rate = getattr(self, name)
            if not 0.0 <= rate <= 1.0:
                raise ValueError(f"{name} rate {rate} must be within [0, 1]")
        if self.burst_max < 1:
            raise ValueError("burst_max must be >= 1")
        self._rng = np.random.default_rng(self.seed)
        self._false = sorted(self.false_ids.items())

    @property
    def active(self) -> bool:
        return bool(self.corrupt or self.drop or self.garbage)

    def apply(self, data: bytes) -> bytes:
        return self.apply_frame(data)[0]

    def apply_frame(self, data: bytes) -> tuple[bytes, bool]:
        """Faulted bytes, and whether ``data`` itself came through intact (garbage may precede it)."""
        rng = self._rng
        counts = self.counts
        intact = True
        out = data
        if self.corrupt or self.drop:
            arr = np.frombuffer(data, dtype=np.uint8).copy()
            if self.corrupt:
                hit = rng.random(arr.size) < self.corrupt
                n_hit = int(hit.sum())
                if n_hit:
                    arr[hit] ^= rng.integers(1, 256, n_hit, dtype=np.uint8)
                    counts.bytes_corrupted += n_hit
                    intact = False
            if self.drop:
                keep = rng.random(arr.size) >= self.drop
                n_lost = arr.size - int(keep.sum())
                if n_lost:
                    arr = arr[keep]
                    counts.bytes_dropped += n_lost
                    intact = False
            if not intact:
                out = arr.tobytes()
        if self.garbage and rng.random() < self.garbage:
            out = self._burst() + out
        return out, intact

    def _burst(self) -> bytes:
        rng = self._rng
        burst = rng.integers(0, 256, int(rng.integers(1, self.burst_max + 1)), dtype=np.uint8).tobytes()
        self.counts.garbage_bursts += 1
        if self._false and rng.random() < 0.5:
            msg_id, length = self._false[int(rng.integers(len(self._false)))]
            burst = SYNC + bytes((length, msg_id, int(rng.integers(256)))) + burst
            self.counts.false_headers += 1
        self.counts.garbage_bytes += len(burst)
        return burst


# (field, member, value): what a damaged frame that still passes CRC-16 can carry; member None = the field itself
OUT_OF_RANGE_VALUES: tuple[tuple[str, str | None, float], ...] = (
    ("position", "lat", 200.0),
    ("attitude", "roll", math.inf),
    ("heading", None, math.nan),
)


@dataclass
class BadTelemetry:
    """Telemetry frames spoilt on purpose, then framed with a good CRC: what the receiver's range check must catch,
    since the CRC cannot.

    Every ``every``-th frame (0: none) carries one out-of-range value (latitude 200°, roll +inf, heading NaN in
    turn, among the fields the mask selects). :meth:`inject` asks, at run time (the simulator's control port,
    modules/dsp/sim/control.py), for the next ``count`` frames that carry a field to carry a given value instead.
    ``sent`` counts the frames spoilt either way, ``injected`` those of :meth:`inject`."""

    every: int = 5
    sent: int = 0
    injected: int = 0
    _frames: int = 0
    _asked: list[list] = field(default_factory=list)  # [path, value, frames still to spoil]
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self) -> None:
        if self.every < 0:
            raise ValueError("every must be >= 0 (0: no periodic spoiling)")

    def inject(self, path: str, value: float, count: int = 1) -> None:
        """Spoil the next ``count`` frames carrying ``path`` (``position.lat``, ``heading``, ``status.mode``...)
        with ``value`` (thread-safe: the control port calls it while the simulator sends)."""
        if count < 1:
            raise ValueError("count must be >= 1")
        with self._lock:
            self._asked.append([path, value, count])

    @property
    def pending(self) -> int:
        """Frames asked for by :meth:`inject` and not spoilt yet."""
        with self._lock:
            return sum(ask[2] for ask in self._asked)

    def spoil(self, msg: p.Telemetry) -> p.Telemetry | None:
        """The spoiled frame when one is asked for or due and its field is present, else None."""
        with self._lock:
            for ask in self._asked:
                bad = _replace_path(msg, ask[0], ask[1])
                if bad is not None:
                    ask[2] -= 1
                    if not ask[2]:
                        self._asked.remove(ask)
                    self.sent += 1
                    self.injected += 1
                    return bad
        self._frames += 1
        if not self.every or self._frames % self.every:
            return None
        start = self.sent
        for i in range(len(OUT_OF_RANGE_VALUES)):
            name, member, value = OUT_OF_RANGE_VALUES[(start + i) % len(OUT_OF_RANGE_VALUES)]
            bad = _replace_path(msg, name if member is None else f"{name}.{member}", value)
            if bad is not None:
                self.sent += 1
                return bad
        return None


def _replace_path(msg: p.Telemetry, path: str, value: float) -> p.Telemetry | None:
    """``msg`` with the field at ``path`` replaced, unchecked (replace() does not validate: on purpose); None when
    the frame does not carry that field (its mask)."""
    name, _, member = path.partition(".")
    current = getattr(msg, name)
    if current is None:
        return None
    bad = value if not member else msgspec.structs.replace(current, **{member: value})
    return msgspec.structs.replace(msg, **{name: bad})


def garble(data: bytes, rng: np.random.Generator, ratio: float) -> bytes:
    """What a UART at the wrong baud rate makes of ``data``: about ``len × ratio`` bytes of noise."""
    n = max(1, round(len(data) * min(ratio, 1.0))) if data else 0
    return rng.integers(0, 256, n, dtype=np.uint8).tobytes()
