"""pymavlink's MAVLink 2 ``common`` dialect: encoders per vehicle, parsers per peer, message signing.

All framing, CRCs and signatures are pymavlink's. One thing is ours: the order of the signature check. pymavlink
records a stream's timestamp before it compares the signature, so a forged frame with a far-future timestamp would
make every later genuine frame of that stream look like a replay; :class:`Parser` checks the signature first and
only then moves the stream's timestamp on. Replay protection is shared by every peer (one :class:`Signing`), so a
frame captured on one link and replayed from another address is refused too.
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Callable
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import common as mav  # noqa: E402

MAVError = mav.MAVError
Message = mav.MAVLink_message
SIGNING_EPOCH = 1420070400
"""MAVLink 2 signing timestamps count 10 µs units from 2015-01-01 00:00 UTC."""


def signing_now(now: float | None = None) -> int:
    return int(((time.time() if now is None else now) - SIGNING_EPOCH) * 100_000)


def read_key(path: str) -> bytes:
    """A signing key file: 32 raw bytes, or 64 hex digits (as MAVProxy's ``signing setup`` passphrase hash is
    usually kept), or any other passphrase, hashed with SHA-256 as MAVProxy does."""
    with open(path, "rb") as f:
        data = f.read()
    text = data.strip()
    if len(data) == 32:
        return data
    if len(text) == 64:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    if not text:
        raise ValueError(f"{path}: the signing key file is empty")
    return hashlib.sha256(text).digest()


class Signing(mav.MAVLinkSigning):
    """One signing state shared by every parser (so a replay is refused whichever link it comes from)."""

    def __init__(self, key: bytes | None, *, refused: Callable[[str], None] | None = None) -> None:
        super().__init__()
        self.secret_key = key
        self.timestamp = signing_now()
        self.sign_outgoing = key is not None
        self.allow_unsigned_callback = (lambda _mav, _msgid: False) if key is not None else None
        self.refused = refused


class Parser(mav.MAVLink):
    """Parses one peer's bytes; with a key, frames not signed by it (or replayed) are dropped and counted."""

    def __init__(self, signing: Signing | None) -> None:
        super().__init__(None, 0, 0)
        if signing is not None and signing.secret_key is not None:
            self.signing = signing
        self.dropped = 0
        self._reported = False

    def check_signature(self, msgbuf: bytearray, srcSystem: int, srcComponent: int) -> bool:  # noqa: N803
        s = self.signing
        assert s.secret_key is not None
        h = hashlib.new("sha256")
        h.update(s.secret_key)
        h.update(msgbuf[:-6])
        if h.digest()[:6] != bytes(msgbuf[-6:]):
            self._refuse(f"bad signature from system {srcSystem}")
            return False
        tlow, thigh = self.mav_sign_unpacker.unpack(msgbuf[-12:-6])
        stamp = tlow + (thigh << 32)
        stream = (msgbuf[-13], srcSystem, srcComponent)
        last = s.stream_timestamps.get(stream)
        if last is not None and stamp <= last:
            self._refuse(f"replayed frame from system {srcSystem} (timestamp {stamp} <= {last})")
            return False
        if last is None and stamp + 6_000_000 < s.timestamp:
            self._refuse(f"stale signed frame from system {srcSystem} (more than a minute old)")
            return False
        s.stream_timestamps[stream] = stamp
        s.timestamp = max(s.timestamp, stamp)
        return True

    def _refuse(self, why: str) -> None:
        self._reported = True
        refused = getattr(self.signing, "refused", None)
        if refused is not None:
            refused(why)

    def feed(self, data: bytes) -> list[Message]:
        """Every whole message in ``data`` (and what earlier calls left); bad CRC, unsigned or forged frames are
        dropped and counted in ``dropped``."""
        out: list[Message] = []
        chunk: bytes = data
        while True:
            try:
                msg = self.parse_char(chunk)
            except MAVError as exc:
                self.dropped += 1
                if "signature" in str(exc) and not self._reported:
                    self._refuse("unsigned frame (signing is required)")
                self._reported = False
                chunk = b""
                continue
            chunk = b""
            if msg is None:
                return out
            if msg.get_type() != "BAD_DATA":
                out.append(msg)


class Encoder(mav.MAVLink):
    """Encodes one vehicle's messages (its system id, its own sequence numbers); ``write`` gets every frame."""

    def __init__(self, sysid: int, write: Callable[[bytes], Any], signing: Signing | None,
                 compid: int = mav.MAV_COMP_ID_AUTOPILOT1) -> None:
        super().__init__(_Sink(write), sysid, compid)
        if signing is not None and signing.secret_key is not None:
            self.signing = signing


class _Sink:
    def __init__(self, write: Callable[[bytes], Any]) -> None:
        self.write = write
