"""SICK/ibeo LD-MRS Ethernet protocol: the 24-byte big-endian data header, commands and replies.

Every message is ``magic 0xAFFEC0C2 | size of previous message | payload size | reserved | device id |
data type | NTP time`` (big-endian) followed by a little-endian payload (reference/protocols.md §2).
The stream parser resynchronises on the magic word: garbage before it is dropped and counted; a header whose
size is impossible, or whose payload disagrees with its own content (a scan's point count), costs only the
four magic bytes, so a good message hidden inside a bogus size is still found. A message cut short (its header
and its scan header promise N points, the bytes stop early and the next message follows) is recognised by the
next message's header inside what its size claims: it is dropped and counted (``cut_short``) and the next message
is parsed from its own magic word, so the good scan after a cut one is not swallowed.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

MAGIC = 0xAFFEC0C2
MAGIC_BYTES = MAGIC.to_bytes(4, "big")
HEADER = struct.Struct(">IIIBBHQ")
HEADER_SIZE = HEADER.size
SCAN_HEADER_SIZE = 44
POINT_SIZE = 10
MAX_PAYLOAD = SCAN_HEADER_SIZE + POINT_SIZE * 0xFFFF
"""Largest payload the LD-MRS can send (a scan of 65535 points); anything bigger is a corrupt header."""
DEFAULT_PORT = 12002
DEFAULT_DEVICE_ID = 7


class DataType(enum.IntEnum):
    COMMAND = 0x2010
    REPLY = 0x2020
    ERROR_WARNING = 0x2030
    SCAN = 0x2202
    OBJECTS = 0x2221
    VEHICLE_STATE = 0x2805
    SENSOR_INFO = 0x7100


class Cmd(enum.IntEnum):
    RESET = 0x0000
    GET_STATUS = 0x0001
    SAVE_CONFIG = 0x0004
    SET_PARAMETER = 0x0010
    GET_PARAMETER = 0x0011
    RESET_DEFAULTS = 0x001A
    START_MEASURE = 0x0020
    STOP_MEASURE = 0x0021
    SET_NTP_SEC = 0x0030
    SET_NTP_FRAC = 0x0031


class Param(enum.IntEnum):
    DATA_OUTPUT_FLAGS = 0x1012
    START_ANGLE = 0x1100
    END_ANGLE = 0x1101
    SCAN_FREQUENCY = 0x1102
    SYNC_ANGLE_OFFSET = 0x1103
    ANGULAR_RESOLUTION_TYPE = 0x1104
    MOUNTING_X = 0x1200
    MOUNTING_Y = 0x1201
    MOUNTING_Z = 0x1202
    MOUNTING_YAW = 0x1203
    MOUNTING_PITCH = 0x1204
    MOUNTING_ROLL = 0x1205


REPLY_ERROR_BIT = 0x8000
COMMAND_VERSION = 3
"""Value libsick_ldmrs writes in the command's reserved word."""

# data output flags: a bit at 0 ENABLES that output
OUTPUT_SCAN = 0x0001
OUTPUT_OBJECTS = 0x0004
OUTPUT_VEHICLE = 0x0008
OUTPUT_ERRORS = 0x0010
RESOLUTION_FOCUSED = 0
RESOLUTION_CONSTANT = 1
RESOLUTION_FLEX = 2


class LdmrsProtocolError(ValueError):
    """A message that cannot be what it claims to be."""


@dataclass(frozen=True, slots=True)
class Message:
    data_type: int
    payload: bytes
    device_id: int = DEFAULT_DEVICE_ID
    ntp: int = 0


def pack_message(data_type: int, payload: bytes, *, device_id: int = DEFAULT_DEVICE_ID, ntp: int = 0,
                 previous_size: int = 0) -> bytes:
    return HEADER.pack(MAGIC, previous_size, len(payload), 0, device_id, data_type, ntp) + payload


def command_payload(cmd: int, param: int | None = None, value: int | None = None) -> bytes:
    """Command body: u16 id, u16 reserved, then u16 parameter (+ u32 value for Set*), little-endian."""
    body = struct.pack("<HH", cmd, COMMAND_VERSION)
    if param is not None:
        body += struct.pack("<H", param)
        if value is not None:
            body += struct.pack("<I", value & 0xFFFFFFFF)
    return body


@dataclass(frozen=True, slots=True)
class Command:
    cmd: int
    param: int | None
    value: int | None


def parse_command(payload: bytes) -> Command:
    if len(payload) < 4:
        raise LdmrsProtocolError(f"command of {len(payload)} bytes")
    cmd = struct.unpack_from("<H", payload)[0]
    param = struct.unpack_from("<H", payload, 4)[0] if len(payload) >= 6 else None
    value = struct.unpack_from("<I", payload, 6)[0] if len(payload) >= 10 else None
    return Command(cmd, param, value)


@dataclass(frozen=True, slots=True)
class Reply:
    cmd: int
    """Command id the reply answers (without the error bit)."""
    ok: bool
    data: bytes
    """Bytes after the echoed command id."""


def parse_reply(payload: bytes) -> Reply:
    if len(payload) < 2:
        raise LdmrsProtocolError(f"reply of {len(payload)} bytes")
    word = struct.unpack_from("<H", payload)[0]
    return Reply(word & ~REPLY_ERROR_BIT & 0xFFFF, not word & REPLY_ERROR_BIT, bytes(payload[2:]))


def reply_payload(cmd: int, data: bytes = b"", *, ok: bool = True) -> bytes:
    return struct.pack("<H", cmd | (0 if ok else REPLY_ERROR_BIT)) + data


_KNOWN_TYPES = frozenset(int(t) for t in DataType)


def _next_header(buf: bytearray, lo: int, hi: int, device_id: int, max_payload: int) -> int | None:
    """Where, in ``buf[lo:hi]``, the header of another message from the same device begins (its magic word, a
    known data type, a possible size); ``-1 - k`` while the magic word at ``k`` lacks the bytes to tell; None when
    there is none. Four magic bytes and a matching device id and type inside a payload by chance: about 2**-40 per
    byte."""
    k = buf.find(MAGIC_BYTES, lo, hi + 3)
    while 0 <= k < hi:
        if len(buf) - k < HEADER_SIZE:
            return -1 - k
        _, _, size, _, dev, data_type, _ = HEADER.unpack_from(buf, k)
        if dev == device_id and data_type in _KNOWN_TYPES and size <= max_payload:
            return k
        k = buf.find(MAGIC_BYTES, k + 1, hi + 3)
    return None


def _payload_consistent(data_type: int, payload: memoryview) -> bool:
    """Content checks that catch a header whose size field lies."""
    if data_type == DataType.SCAN:
        if len(payload) < SCAN_HEADER_SIZE:
            return False
        n = payload[28] | (payload[29] << 8)
        return len(payload) == SCAN_HEADER_SIZE + POINT_SIZE * n
    if data_type == DataType.REPLY:
        return len(payload) >= 2
    if data_type == DataType.ERROR_WARNING:
        return len(payload) >= 8
    return True


class MessageParser:
    """Incremental LD-MRS stream parser with magic-word resynchronisation and counters."""

    def __init__(self, max_payload: int = MAX_PAYLOAD) -> None:
        self._buf = bytearray()
        self._max = max_payload
        self.messages = 0
        self.discarded_bytes = 0
        self.bad_size = 0
        self.size_mismatch = 0
        self.cut_short = 0
        self._searched = 0
        """Bytes of the message waited for (at the buffer's start) already searched for a next header: a long
        message arriving in small reads is searched once, not once per read."""

    @property
    def damaged(self) -> int:
        """Messages refused so far: impossible size, size disagreeing with the content, cut short."""
        return self.bad_size + self.size_mismatch + self.cut_short

    @property
    def pending(self) -> int:
        return len(self._buf)

    def feed(self, chunk: bytes) -> list[Message]:
        buf = self._buf
        buf += chunk
        out: list[Message] = []
        pos = 0
        n = len(buf)
        searched, self._searched = self._searched, 0
        while True:
            start = buf.find(MAGIC_BYTES, pos)
            if start < 0:
                # keep a possible partial magic word at the end
                keep = min(3, n - pos)
                self.discarded_bytes += n - pos - keep
                pos = n - keep
                break
            self.discarded_bytes += start - pos
            pos = start
            if n - pos < HEADER_SIZE:
                break
            _, _, size, _, device_id, data_type, ntp = HEADER.unpack_from(buf, pos)
            if size > self._max:
                self.bad_size += 1
                self.discarded_bytes += 4
                pos += 4
                continue
            end = pos + HEADER_SIZE + size
            lo = max(pos + HEADER_SIZE, pos + searched)
            searched = 0  # valid for the message at the buffer's start only
            nxt = _next_header(buf, lo, min(n, end), device_id, self._max)
            if nxt is not None and nxt < 0:  # a magic word inside the claimed payload: wait for what it starts
                self._searched = -nxt - 1 - pos
                break
            if nxt is not None:  # the next message starts inside this one's claimed size: this one was cut short
                self.cut_short += 1
                self.discarded_bytes += nxt - pos
                pos = nxt
                continue
            if n < end:
                self._searched = max(0, n - 3 - pos)
                break
            payload = memoryview(buf)[pos + HEADER_SIZE:end]
            if not _payload_consistent(data_type, payload):
                payload.release()
                self.size_mismatch += 1
                self.discarded_bytes += 4
                pos += 4
                continue
            out.append(Message(data_type, bytes(payload), device_id, ntp))
            payload.release()
            self.messages += 1
            pos = end
        del buf[:pos]
        return out
