"""Bounded decoding of requests: a size and a nesting depth checked before msgspec sees the bytes.

msgspec decodes nested msgpack recursively: a 100,000-deep map on a request key raised ``RecursionError`` (not a
``msgspec.MsgspecError``), so the request got no reply and, on the answering thread, the query was never dropped
(issue 32 item 7). :func:`check` walks the msgpack structure iteratively, without building anything, and refuses
what is larger or deeper than a request may be with :class:`RequestRefused`, a ``msgspec.DecodeError``: every
caller that answers a malformed request with a clear refusal does the same for these.
"""

from __future__ import annotations

import struct
from typing import Any, TypeVar

import msgspec

MAX_REQUEST_BYTES = 1 << 20
"""1 MiB: far above any task, world edit or synchronised start (a 10,000-waypoint path is ~0.4 MiB)."""
MAX_REQUEST_DEPTH = 32
"""Nesting of maps and arrays; the deepest request struct nests fewer than 8."""

T = TypeVar("T")


class RequestRefused(msgspec.DecodeError):
    """A request larger or deeper than allowed: refused before decoding."""


# msgpack first bytes whose length/count follows in the next 1, 2 or 4 bytes: (length bytes, kind)
_SIZED = {0xC4: (1, "b"), 0xC5: (2, "b"), 0xC6: (4, "b"),  # bin
          0xD9: (1, "b"), 0xDA: (2, "b"), 0xDB: (4, "b"),  # str
          0xC7: (1, "x"), 0xC8: (2, "x"), 0xC9: (4, "x"),  # ext (+1 type byte)
          0xDC: (2, "a"), 0xDD: (4, "a"),  # array
          0xDE: (2, "m"), 0xDF: (4, "m")}  # map
_FIXED = {0xC0: 0, 0xC2: 0, 0xC3: 0, 0xCA: 4, 0xCB: 8, 0xCC: 1, 0xCD: 2, 0xCE: 4, 0xCF: 8, 0xD0: 1, 0xD1: 2,
          0xD2: 4, 0xD3: 8, 0xD4: 2, 0xD5: 3, 0xD6: 5, 0xD7: 9, 0xD8: 17}
_UINT = {1: struct.Struct(">B"), 2: struct.Struct(">H"), 4: struct.Struct(">I")}


def check(payload: bytes, *, max_bytes: int = MAX_REQUEST_BYTES, max_depth: int = MAX_REQUEST_DEPTH) -> None:
    """Raise :class:`RequestRefused` when ``payload`` is over ``max_bytes`` or nests maps/arrays deeper than
    ``max_depth``. Malformed msgpack is left for the decoder to name (this only bounds the work)."""
    if len(payload) > max_bytes:
        raise RequestRefused(f"request of {len(payload)} bytes refused: at most {max_bytes}")
    pending: list[int] = []  # items still to read in each open container
    i, n = 0, len(payload)
    while i < n:
        b = payload[i]
        i += 1
        items = 0
        if b <= 0x7F or b >= 0xE0:  # fixint
            pass
        elif 0x80 <= b <= 0x8F:
            items = 2 * (b & 0x0F)
        elif 0x90 <= b <= 0x9F:
            items = b & 0x0F
        elif 0xA0 <= b <= 0xBF:
            i += b & 0x1F
        elif b in _FIXED:
            i += _FIXED[b]
        elif b in _SIZED:
            width, kind = _SIZED[b]
            if i + width > n:
                return
            size = _UINT[width].unpack_from(payload, i)[0]
            i += width
            if kind == "b":
                i += size
            elif kind == "x":
                i += 1 + size
            else:
                items = size * (2 if kind == "m" else 1)
        else:  # 0xC1: never used; the decoder names it
            return
        if items:
            if len(pending) >= max_depth:
                raise RequestRefused(f"request nested deeper than {max_depth} maps/arrays refused")
            if items > n:  # more items announced than bytes left: the decoder refuses it as truncated
                return
            pending.append(items)
            continue
        while pending:  # a scalar (or an empty container) completes one item of each container it closes
            pending[-1] -= 1
            if pending[-1]:
                break
            pending.pop()
        if not pending and i < n:
            return  # trailing bytes: the decoder's to refuse
    return


def decode(decoder: msgspec.msgpack.Decoder[Any], payload: bytes, *, max_bytes: int = MAX_REQUEST_BYTES,
           max_depth: int = MAX_REQUEST_DEPTH) -> Any:
    """``decoder.decode(payload)`` once :func:`check` has passed it."""
    check(payload, max_bytes=max_bytes, max_depth=max_depth)
    return decoder.decode(payload)
