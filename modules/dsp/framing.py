"""Frame building and the receive state machine (docs/dsp_protocol.md §2, §6). Pure: bytes in, frames out.

The parser keeps a bounded buffer and resynchronises after garbage, lost bytes, a bad CRC, an unknown id or
an impossible length. A rejected candidate only ever costs its first byte: the search restarts at the byte
after the false start, so a real frame that begins inside a false one is still found (the backtracking rule
that rust-mavlink adopted after pymavlink's whole-frame discard swallowed good frames). The scan jumps with
``bytearray.find`` on the two sync bytes and checks the CRC with ``binascii.crc_hqx`` (C), so the hot path
has no per-byte Python loop.
"""

from __future__ import annotations

from binascii import crc_hqx
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import NamedTuple

SYNC = b"\xa5\x5a"
HEADER_SIZE = 5  # sync ×2, LEN, ID, SEQ
CRC_SIZE = 2
MAX_PAYLOAD = 128
MAX_FRAME = HEADER_SIZE + MAX_PAYLOAD + CRC_SIZE

CRC_INIT = 0xFFFF  # CRC-16/IBM-3740 ("CCITT-FALSE"): poly 0x1021, init 0xFFFF, no reflection, no xorout
CHUNK = 4096  # input is scanned in slices of at most this size, which bounds the buffer
_SYNC1 = SYNC[0]


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/IBM-3740 of ``data``; ``crc16(b"123456789") == 0x29B1``."""
    return crc_hqx(data, CRC_INIT)


class Frame(NamedTuple):
    """A frame that passed every check: id, sequence number, raw payload."""

    msg_id: int
    seq: int
    payload: bytes


def build_frame(msg_id: int, seq: int, payload: bytes) -> bytes:
    """Wrap a payload: sync, LEN, ID, SEQ, payload, CRC (little-endian)."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds MAX_PAYLOAD={MAX_PAYLOAD}")
    if not 0 <= msg_id <= 0xFF or not 0 <= seq <= 0xFF:
        raise ValueError(f"msg_id {msg_id} and seq {seq} must fit in a byte")
    body = bytes((len(payload), msg_id, seq)) + payload
    crc = crc_hqx(body, CRC_INIT)
    return SYNC + body + bytes((crc & 0xFF, crc >> 8))


@dataclass
class FramingStats:
    """What the parser accepted and what it dropped, by reason."""

    frames: int = 0  # frames delivered
    bytes_in: int = 0
    bytes_discarded: int = 0  # every byte not part of a delivered frame (garbage + false-start bytes)
    bad_crc: int = 0
    unknown_id: int = 0
    bad_length: int = 0  # LEN not valid for that id
    oversize: int = 0  # LEN > MAX_PAYLOAD
    truncated: int = 0  # incomplete candidate given up after the line went idle
    max_buffered: int = 0  # high-water mark of the receive buffer, bytes

    @property
    def dropped_frames(self) -> int:
        """False starts and damaged frames rejected (each counted once, by its first reason)."""
        return self.bad_crc + self.unknown_id + self.bad_length + self.oversize + self.truncated

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class FrameParser:
    """Receive state machine over a bounded buffer.

    ``lengths`` maps each message id this side may receive to the payload lengths valid for it; any other
    id is an unknown id. ``feed()`` returns the frames completed by new bytes; ``flush_pending()`` is called
    when the line has gone idle so an incomplete false start cannot hold back the frames queued behind it.
    """

    def __init__(self, lengths: Mapping[int, Iterable[int]]) -> None:
        self._allowed: list[frozenset[int] | None] = [None] * 256
        for msg_id, lens in lengths.items():
            valid = frozenset(n for n in lens if 0 <= n <= MAX_PAYLOAD)
            if not valid:
                raise ValueError(f"message id {msg_id:#04x} has no valid payload length")
            self._allowed[msg_id] = valid
        self._buf = bytearray()
        self.stats = FramingStats()

    @property
    def buffered(self) -> int:
        """Bytes held waiting for the rest of a frame (always < MAX_FRAME + CHUNK)."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        out: list[Frame] = []
        n = len(data)
        self.stats.bytes_in += n
        if n <= CHUNK:
            self._buf += data
            self._scan(out, False)
        else:
            view = memoryview(data)
            for start in range(0, n, CHUNK):
                self._buf += view[start:start + CHUNK]
                self._scan(out, False)
        return out

    def flush_pending(self) -> list[Frame]:
        """The line is idle: give up the incomplete candidate at the head and rescan what follows it."""
        out: list[Frame] = []
        if self._buf:
            self._scan(out, True)
        return out

    def reset(self) -> None:
        """Forget buffered bytes (counted as discarded), e.g. after reopening the port."""
        self.stats.bytes_discarded += len(self._buf)
        self._buf.clear()

    def _scan(self, out: list[Frame], idle: bool) -> None:
        buf = self._buf
        n = len(buf)
        st = self.stats
        if n > st.max_buffered:
            st.max_buffered = n
        allowed = self._allowed
        find = buf.find
        pos = 0
        discarded = 0
        delivered = len(out)
        while True:
            i = find(SYNC, pos)
            if i < 0:
                # keep a trailing first sync byte: its partner may be in the next read
                end = n - 1 if (not idle and n > pos and buf[n - 1] == _SYNC1) else n
                discarded += end - pos
                pos = end
                break
            discarded += i - pos
            if n - i < HEADER_SIZE:
                if idle:
                    st.truncated += 1
                    discarded += 1
                    pos = i + 1
                    continue
                pos = i
                break
            length = buf[i + 2]
            lens = allowed[buf[i + 3]]
            if length > MAX_PAYLOAD:
                st.oversize += 1
            elif lens is None:
                st.unknown_id += 1
            elif length not in lens:
                st.bad_length += 1
            else:
                end = i + HEADER_SIZE + length + CRC_SIZE
                if end > n:
                    if not idle:
                        pos = i
                        break
                    st.truncated += 1
                elif crc_hqx(buf[i + 2:end - 2], CRC_INIT) == buf[end - 2] | (buf[end - 1] << 8):
                    out.append(Frame(buf[i + 3], buf[i + 4], bytes(buf[i + HEADER_SIZE:end - 2])))
                    pos = end
                    continue
                else:
                    st.bad_crc += 1
            # false start: drop only its first byte and search again from the next one
            discarded += 1
            pos = i + 1
        st.bytes_discarded += discarded
        st.frames += len(out) - delivered
        if pos:
            del buf[:pos]
