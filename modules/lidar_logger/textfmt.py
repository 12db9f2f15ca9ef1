"""The text log's point lines, formatted in numpy instead of one ``%`` conversion per number.

Every line ``num; x,y,z; width; flags; layer; echo; offset; valid; 0`` is a row of 4-byte *cells* (digit
groups, separators with an optional sign). All numbers become integers (x, y, z as round(v·1e8) split into
integer and 8-digit fraction, echo width as cm split into metres and 2 digits), their decimal digits are
looked up a column at a time for the whole scan, a mask marks which characters exist (no leading zeros, no
absent sign), and ``np.compress`` keeps them. The bytes are exactly what ``POINT_FMT % row`` would give:

- ``%.8f`` rounds the exact binary value; round(v·1e8) in float64 agrees except when v·1e8 lies within a
  rounding error of a half; those few values (|frac − 0.5| < 1e-4) are formatted by Python and parsed back;
- a negative value that rounds to zero keeps its sign (``-0.00000000``), as Python prints it;
- any number too wide for the cells (|x| ≥ 1e7 m, an integer ≥ 1e8) sends the whole scan to the ``%`` path.
"""

from __future__ import annotations

import itertools

import numpy as np

POINT_FMT = "%d; %.8f,%.8f,%.8f; %.2f; %d; %d; %d; %d; %d; %d\n"

_LIMIT = 10**8
_DIGITS4 = np.array([b"%04d" % k for k in range(10_000)]).view(np.uint32)
"""Four ASCII digits of 0..9999 (zero-padded), one uint32 each: one gather formats a whole column."""
_SIGNIFICANT4 = np.array([bytes(4 - len(str(k))) + b"\x01" * len(str(k)) for k in range(10_000)]).view(np.uint32)
"""1 for the characters of 0..9999 printed without leading zeros, 0 for the padding."""
_ONES4 = np.uint32(0x01010101)


def _scaled_1e8(v: np.ndarray) -> np.ndarray:
    """round(|v|·1e8) exactly as ``%.8f`` rounds (the sign is handled apart)."""
    scaled = np.abs(v) * 1e8
    out = np.rint(scaled).astype(np.int64)
    frac = scaled - np.floor(scaled)
    for idx in np.argwhere(np.abs(frac - 0.5) < 1e-4):
        i = tuple(idx)
        out[i] = int(f"{abs(float(v[i])):.8f}".replace(".", ""))
    return out


def _cell(text: bytes) -> tuple[np.uint32, np.uint32]:
    """A literal of up to 4 characters as a cell: its bytes (NUL padded) and its mask."""
    chars = np.frombuffer(text.ljust(4, b"\0"), np.uint32)[0]
    mask = np.frombuffer(bytes(1 if i < len(text) else 0 for i in range(4)), np.uint32)[0]
    return chars, mask


_DIGITS2 = np.frombuffer(b"".join(b"%02d\0\0" % k for k in range(100)), np.uint32)
"""Two digits (zero-padded) of 0..99 in a cell: the echo width's centimetres."""
_SHOW2 = np.uint32(0x0101)
_SEMI, _SEMI_SHOW = _cell(b"; ")
_SEMI_MINUS, _ = _cell(b"; -")
_COMMA, _COMMA_SHOW = _cell(b",")
_COMMA_MINUS, _ = _cell(b",-")
_DOT, _DOT_SHOW = _cell(b".")
_END, _END_SHOW = _cell(b"; 0\n")
_SEMI_SIGN = np.uint32(0x010000)  # the '-' of "; -"
_COMMA_SIGN = np.uint32(0x0100)  # the '-' of ",-"
_LAST_DIGIT = np.uint32(0x01000000)


def format_points(xyz: np.ndarray, width_cm: np.ndarray, flags: np.ndarray, layer: np.ndarray,
                  echo: np.ndarray, offset_us: np.ndarray) -> bytes:
    """The point lines of one scan (numbered from 1), byte-identical to ``POINT_FMT`` applied row by row.

    Each line is a row of 4-byte *cells* (a 4-digit group, a separator with an optional minus sign), each cell
    with a 4-byte mask of the characters printed; the cells are filled a column at a time (one table gather
    per digit group) and ``np.compress`` keeps the masked characters, one pass for the whole scan.
    """
    n = len(xyz)
    if n == 0:
        return b""
    width, flag, lay, ech = (np.asarray(c, dtype=np.int64) for c in (width_cm, flags, layer, echo))
    offset = np.asarray(offset_us, dtype=np.int64)
    if not np.all(np.abs(xyz) < 1e7):
        return _format_points_slow(xyz, width_cm, flags, layer, echo, offset_us)
    scaled = _scaled_1e8(xyz)
    ints, fracs = scaled // 100_000_000, scaled % 100_000_000
    num = np.arange(1, n + 1, dtype=np.int64)
    abs_offset = np.abs(offset)
    naturals = (num, ints, width, flag, lay, ech, abs_offset)
    if min(int(v.min()) for v in naturals) < 0 or max(int(v.max()) for v in naturals) >= _LIMIT:
        return _format_points_slow(xyz, width_cm, flags, layer, echo, offset_us)
    cells: list[tuple[np.ndarray | np.uint32, np.ndarray | np.uint32]] = []

    def natural(v: np.ndarray) -> None:  # no leading zeros; 0 prints as "0"
        if int(v.max()) < 10_000:
            cells.append((_DIGITS4[v], _SIGNIFICANT4[v]))
        else:
            hi, lo = v // 10_000, v % 10_000
            big = hi > 0
            cells.append((_DIGITS4[hi], np.where(big, _SIGNIFICANT4[hi], 0)))
            cells.append((_DIGITS4[lo], np.where(big, _ONES4, _SIGNIFICANT4[lo])))

    negative = np.signbit(xyz)  # -0.0 prints its sign, as Python does
    natural(num)
    for k, (sep, show, sign) in enumerate(((_SEMI_MINUS, _SEMI_SHOW, _SEMI_SIGN),
                                           (_COMMA_MINUS, _COMMA_SHOW, _COMMA_SIGN),
                                           (_COMMA_MINUS, _COMMA_SHOW, _COMMA_SIGN))):
        cells.append((sep, np.where(negative[:, k], show | sign, show)))
        natural(ints[:, k])
        cells.append((_DOT, _DOT_SHOW))
        cells.append((_DIGITS4[fracs[:, k] // 10_000], _ONES4))
        cells.append((_DIGITS4[fracs[:, k] % 10_000], _ONES4))
    cells.append((_SEMI, _SEMI_SHOW))
    natural(width // 100)
    cells.append((_DOT, _DOT_SHOW))
    cells.append((_DIGITS2[width % 100], _SHOW2))
    for column in (flag, lay, ech):
        cells.append((_SEMI, _SEMI_SHOW))
        natural(column)
    cells.append((_SEMI_MINUS, np.where(offset < 0, _SEMI_SHOW | _SEMI_SIGN, _SEMI_SHOW)))
    natural(abs_offset)
    cells.append((_SEMI, _SEMI_SHOW))
    cells.append((_DIGITS4[(flag == 0).astype(np.int64)], _LAST_DIGIT))
    cells.append((_END, _END_SHOW))
    chars = np.empty((n, len(cells)), dtype=np.uint32)
    mask = np.empty((n, len(cells)), dtype=np.uint32)
    for j, (c, m) in enumerate(cells):
        chars[:, j] = c
        mask[:, j] = m
    return np.compress(mask.view(np.uint8).ravel().view(bool), chars.view(np.uint8).ravel()).tobytes()


def _format_points_slow(xyz: np.ndarray, width_cm: np.ndarray, flags: np.ndarray, layer: np.ndarray,
                        echo: np.ndarray, offset_us: np.ndarray) -> bytes:
    """One ``%`` over the whole scan: the reference the fast path must match, and its fallback."""
    n = len(xyz)
    flags = np.asarray(flags)
    columns = (
        range(1, n + 1), xyz[:, 0].tolist(), xyz[:, 1].tolist(), xyz[:, 2].tolist(),
        (np.asarray(width_cm) / 100.0).tolist(), flags.tolist(), np.asarray(layer).tolist(),
        np.asarray(echo).tolist(), np.asarray(offset_us).tolist(), (flags == 0).astype(np.int64).tolist(),
        itertools.repeat(0, n),
    )
    text = (POINT_FMT * n) % tuple(itertools.chain.from_iterable(zip(*columns, strict=False)))
    return text.encode("ascii")
