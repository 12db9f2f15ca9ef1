"""Xsens MT binary protocol ("Xbus") framing: build frames, and cut a byte stream back into frames.

Frame: ``FA BID MID LEN [LENEXT_hi LENEXT_lo] DATA CS`` with LEN 0xFF meaning a 16-bit big-endian extended
length, and CS chosen so that BID+MID+LEN(+LENEXT)+DATA+CS ≡ 0 (mod 256); the preamble is not summed
(reference/protocols.md §1.1). The parser resynchronises on any damage: a bad checksum or an impossible length
costs exactly one byte (the false preamble), so a good frame right behind a corrupt one is never lost.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

PREAMBLE = 0xFA
BID_MASTER = 0xFF
EXT_LEN_CODE = 0xFF
MAX_SHORT_LEN = 254
MAX_DATA_LEN = 8192
"""``CMT_MAXDATALEN``: a longer extended length is a corrupt header, not a frame."""


class MID(enum.IntEnum):
    """Message ids of an MTi-G session; the acknowledgement of a request is ``MID + 1``."""

    REQ_DID = 0x00
    DEVICE_ID = 0x01
    SET_PERIOD = 0x04
    REQ_DATA_LENGTH = 0x0A
    DATA_LENGTH = 0x0B
    REQ_CONFIGURATION = 0x0C
    GOTO_MEASUREMENT = 0x10
    REQ_FW_REV = 0x12
    SET_BAUDRATE = 0x18
    REQ_PRODUCT_CODE = 0x1C
    GOTO_CONFIG = 0x30
    MTDATA = 0x32
    REQ_DATA = 0x34
    MTDATA2 = 0x36
    WAKEUP = 0x3E
    WAKEUP_ACK = 0x3F
    RESET = 0x40
    ERROR = 0x42
    REQ_UTC_TIME = 0x60
    SET_SCENARIO = 0x64
    SET_GPS_LEVER_ARM = 0x68
    SET_OUTPUT_MODE = 0xD0
    SET_OUTPUT_SETTINGS = 0xD2
    SET_OUTPUT_SKIP_FACTOR = 0xD4


ERROR_CODES = {
    0x03: "invalid period",
    0x04: "invalid message",
    0x1E: "timer overflow",
    0x20: "invalid baudrate",
    0x21: "invalid parameter",
}


def ack_of(mid: int) -> int:
    return (mid + 1) & 0xFF


@dataclass(frozen=True, slots=True)
class Frame:
    mid: int
    data: bytes
    bid: int = BID_MASTER


def build_frame(mid: int, data: bytes = b"", bid: int = BID_MASTER) -> bytes:
    """Encode one frame; lengths of 255 and more use the extended length field."""
    n = len(data)
    if n > MAX_DATA_LEN:
        raise ValueError(f"Xbus data of {n} bytes exceeds the maximum of {MAX_DATA_LEN}")
    if n <= MAX_SHORT_LEN:
        head = bytes((bid, mid & 0xFF, n))
    else:
        head = bytes((bid, mid & 0xFF, EXT_LEN_CODE, n >> 8, n & 0xFF))
    body = head + bytes(data)
    return bytes((PREAMBLE,)) + body + bytes(((-sum(body)) & 0xFF,))


class FrameParser:
    """Incremental parser: ``feed`` bytes as they arrive, get complete, checksum-verified frames back.

    Counters say what was thrown away: ``bad_checksum`` candidate frames, ``bad_length`` impossible extended
    lengths, ``discarded_bytes`` bytes skipped while looking for a preamble.
    """

    def __init__(self, max_data: int = MAX_DATA_LEN) -> None:
        self._buf = bytearray()
        self._max = max_data
        self.frames = 0
        self.bad_checksum = 0
        self.bad_length = 0
        self.discarded_bytes = 0

    @property
    def pending(self) -> int:
        """Bytes held while waiting for the rest of a frame."""
        return len(self._buf)

    @property
    def damaged(self) -> int:
        """Candidate frames refused so far (bad checksum, impossible length)."""
        return self.bad_checksum + self.bad_length

    def feed(self, chunk: bytes) -> list[Frame]:
        buf = self._buf
        buf += chunk
        out: list[Frame] = []
        pos = 0
        n = len(buf)
        while True:
            start = buf.find(PREAMBLE, pos)
            if start < 0:
                self.discarded_bytes += n - pos
                pos = n
                break
            self.discarded_bytes += start - pos
            pos = start
            if n - pos < 4:
                break
            length = buf[pos + 3]
            head = 4
            if length == EXT_LEN_CODE:
                if n - pos < 6:
                    break
                length = (buf[pos + 4] << 8) | buf[pos + 5]
                head = 6
                if length > self._max:
                    self.bad_length += 1
                    self.discarded_bytes += 1
                    pos += 1
                    continue
            total = head + length + 1
            if n - pos < total:
                break
            if sum(buf[pos + 1:pos + total]) & 0xFF:
                self.bad_checksum += 1
                self.discarded_bytes += 1
                pos += 1
                continue
            data = bytes(buf[pos + head:pos + head + length])
            out.append(Frame(mid=buf[pos + 2], data=data, bid=buf[pos + 1]))
            self.frames += 1
            pos += total
        del buf[:pos]
        return out
