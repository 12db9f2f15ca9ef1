"""Damaged-line experiments shared by the tests and bench/dsp.py: make traffic, damage it, score a receiver.

``dsp_traffic`` makes unique DSP → PC frames (telemetry of several masks, ACKs, ERRORs); ``fault_stream``
corrupts and drops bytes and inserts garbage bursts (half with false headers), remembering which frames came
through intact; ``score`` matches what a receiver delivered against what was sent, in order.
"""

from __future__ import annotations

import struct
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bbcs.contracts import dsp as p
from modules.dsp.codec import DSP_TO_PC_LENGTHS, encode_payload
from modules.dsp.framing import SYNC, Frame, build_frame

F = p.TelemetryField
TYPICAL_MASKS = (
    p.TELEMETRY_ALL,
    int(F.POSITION | F.ATTITUDE | F.VELOCITY | F.HEADING | F.STATUS | F.ERROR),
    int(F.POSITION | F.STATUS),
    int(F.STATUS | F.PAN_TILT | F.ENGINE),
)


def random_telemetry(rng: np.random.Generator, mask: int) -> p.Telemetry:
    """Telemetry with every field of ``mask`` filled with random (binary32-exact) values within the ranges the
    protocol's types declare (a frame outside them is dropped by the DSP process)."""
    def f(alias: object = p.TelSpeed) -> float:
        meta = typing.get_args(alias)[1]
        return float(np.float32(np.clip(rng.normal(0.0, 50.0), meta.ge, meta.le)))

    fields: dict[str, object] = {}
    if mask & F.POSITION:
        fields["position"] = p.TelPosition(lat=int(rng.integers(-9e8, 9e8)) / 1e7,
                                        lon=int(rng.integers(-18e8, 18e8)) / 1e7,
                                        alt=f(p.TelAlt))
    if mask & F.ATTITUDE:
        roll, pitch, yaw = f(p.Angle180), f(p.Angle90), f(p.Angle180)
        fields["attitude"] = p.TelAttitude(roll=roll, pitch=pitch, yaw=-180.0 if yaw >= 180.0 else yaw)  # [-180, 180)
    if mask & F.VELOCITY:
        fields["velocity"] = p.TelVelocity(vn=f(), ve=f(), vd=f())
    if mask & F.ANGULAR_RATE:
        fields["angular_rate"] = p.AngularRate(p=f(p.TelRate), q=f(p.TelRate), r=f(p.TelRate))
    if mask & F.HEADING:
        fields["heading"] = float(np.float32(rng.uniform(-180, 179.9)))
    if mask & F.STATUS:
        fields["status"] = p.DspStatus(mode=int(rng.integers(0, 7)), tracking=bool(rng.integers(2)),
                                       path_valid=bool(rng.integers(2)), airborne=bool(rng.integers(2)),
                                       queue_length=int(rng.integers(0, 512)))
    if mask & F.NAV:
        fields["nav"] = p.NavTarget(lat=int(rng.integers(-9e5, 9e5)) / 1e4,
                                    lon=int(rng.integers(-18e5, 18e5)) / 1e4,
                                    alt=f(p.TelAlt), distance=abs(f(p.TelDistance)))
    if mask & F.SPEED:
        fields["speed"] = p.SpeedInfo(commanded=abs(f(p.TelCommandedSpeed)), ground=abs(f(p.TelGroundSpeed)))
    if mask & F.PAN_TILT:
        fields["pan_tilt"] = p.PanTiltState(mode=int(rng.integers(0, 3)), pan=f(p.Angle180), tilt=f(p.Angle90))
    if mask & F.ERROR:
        fields["error_code"] = int(rng.integers(0, 10))
    if mask & F.ENGINE:
        fields["engine"] = p.Engine(rotor_rpm=abs(f(p.TelRpm)) * 30, battery_v=abs(f(p.TelVolts)) / 2)
    return p.Telemetry(time_ms=0, **fields)  # type: ignore[arg-type]


def dsp_traffic(n: int, seed: int = 1, masks: Sequence[int] = TYPICAL_MASKS, templates: int = 256,
                telemetry_share: float = 0.85) -> list[bytes]:
    """``n`` distinct DSP → PC frames: telemetry (time_ms = frame index), then ACKs and a few ERRORs.

    By default ~85 % telemetry, ~12 % ACK, ~3 % ERROR; ``telemetry_share=1`` gives telemetry only.
    """
    rng = np.random.default_rng(seed)
    payloads = [encode_payload(random_telemetry(rng, masks[i % len(masks)])) for i in range(templates)]
    kinds = rng.random(n)
    picks = rng.integers(0, templates, n)
    ack = struct.Struct("<BBH")
    err = struct.Struct("<IHB")
    frames: list[bytes] = []
    for i in range(n):
        if kinds[i] < telemetry_share:
            payload = bytearray(payloads[picks[i]])
            struct.pack_into("<I", payload, 0, i & 0xFFFFFFFF)
            frames.append(build_frame(p.MsgId.TELEMETRY, i & 0xFF, bytes(payload)))
        elif kinds[i] < telemetry_share + (1.0 - telemetry_share) * 0.8:
            payload = ack.pack(i & 0x3F, (i >> 6) & 0xFF, (i >> 14) & 0xFF)
            frames.append(build_frame(p.MsgId.ACK, i & 0xFF, payload))
        else:
            frames.append(build_frame(p.MsgId.ERROR, i & 0xFF, err.pack(i, 5, 0)))
    return frames


@dataclass
class Damaged:
    stream: bytes
    intact: np.ndarray  # bool per frame: its own bytes arrived unchanged
    bytes_corrupted: int
    bytes_dropped: int
    garbage_bursts: int
    false_headers: int


def fault_stream(frames: Sequence[bytes], *, corrupt: float = 0.01, drop: float = 0.0, garbage: float = 0.02,
                 burst_max: int = 48, seed: int = 2,
                 false_ids: Mapping[int, int] | None = None) -> Damaged:
    """Damage a frame sequence the way a bad serial line does (vectorised: fast enough for 10^5 frames)."""
    rng = np.random.default_rng(seed)
    if false_ids is None:
        false_ids = {i: max(lens) for i, lens in DSP_TO_PC_LENGTHS.items()}
    false = sorted(false_ids.items())
    sizes = np.fromiter((len(f) for f in frames), dtype=np.int64, count=len(frames))
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    data = np.frombuffer(b"".join(frames), dtype=np.uint8).copy()
    hit = rng.random(data.size) < corrupt
    data[hit] ^= rng.integers(1, 256, int(hit.sum()), dtype=np.uint8)
    lost = rng.random(data.size) < drop if drop else np.zeros(data.size, dtype=bool)
    touched = hit | lost
    damaged = np.add.reduceat(touched, starts) > 0 if len(frames) else np.zeros(0, dtype=bool)
    lossy = np.add.reduceat(lost, starts) > 0 if len(frames) and drop else np.zeros(len(frames), dtype=bool)
    bursts = rng.random(len(frames)) < garbage
    buf = data.tobytes()
    pieces: list[bytes] = []
    n_false = 0
    for i in range(len(frames)):
        s = int(starts[i])
        e = s + int(sizes[i])
        if bursts[i]:
            burst = rng.bytes(int(rng.integers(1, burst_max + 1)))
            if false and rng.random() < 0.5:
                msg_id, length = false[int(rng.integers(len(false)))]
                burst = SYNC + bytes((length, msg_id, int(rng.integers(256)))) + burst
                n_false += 1
            pieces.append(burst)
        pieces.append(data[s:e][~lost[s:e]].tobytes() if lossy[i] else buf[s:e])
    return Damaged(stream=b"".join(pieces), intact=~damaged, bytes_corrupted=int(hit.sum()),
                   bytes_dropped=int(lost.sum()), garbage_bursts=int(bursts.sum()), false_headers=n_false)


@dataclass
class Score:
    sent: int
    intact: int
    recovered_intact: int
    bad_accepted: int  # delivered frames that are not, byte for byte, a frame that was sent

    @property
    def recovery_ratio(self) -> float:
        return self.recovered_intact / self.intact if self.intact else 1.0


def score(frames: Sequence[bytes], intact: np.ndarray, received: Sequence[Frame]) -> Score:
    """Match delivered frames to sent ones in order; anything unmatched is a damaged frame that got in."""
    keys = [(f[3], f[4], f[5:-2]) for f in frames]
    recovered = np.zeros(len(frames), dtype=bool)
    bad = 0
    j = 0
    for r in received:
        key = (r.msg_id, r.seq, r.payload)
        k = j
        limit = min(len(keys), j + 256)
        while k < limit and keys[k] != key:
            k += 1
        if k < limit:
            recovered[k] = True
            j = k + 1
        else:
            bad += 1
    return Score(sent=len(frames), intact=int(intact.sum()), recovered_intact=int((recovered & intact).sum()),
                 bad_accepted=bad)
