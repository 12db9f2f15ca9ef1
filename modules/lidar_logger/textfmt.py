"""The text log's point lines, formatted in numpy instead of one ``%`` conversion per number.

Every line ``num; x,y,z; width; flags; layer; echo; offset; valid; 0`` is a row of fixed-width *cells*:
``[sign][digits...][separator]``. All numbers become integers (x, y, z as round(v·1e8) split into integer
and 8-digit fraction, echo width as cm split into metres and 2 digits), their decimal digits are computed for
the whole scan in one array operation, a mask marks which characters exist (no leading zeros, no absent
sign), and ``chars[mask]`` is the text. The bytes are exactly what ``POINT_FMT % row`` would give:

- ``%.8f`` rounds the exact binary value; round(v·1e8) in float64 agrees except when v·1e8 lies within a
  rounding error of a half; those few values (|frac − 0.5| < 1e-4) are formatted by Python and parsed back;
- a negative value that rounds to zero keeps its sign (``-0.00000000``), as Python prints it;
- any number too wide for the cells (|x| ≥ 1e7 m, an integer ≥ 1e8) sends the whole scan to the ``%`` path.
"""

from __future__ import annotations

import functools
import itertools

import numpy as np

POINT_FMT = "%d; %.8f,%.8f,%.8f; %.2f; %d; %d; %d; %d; %d; %d\n"

_LIMIT = 10**8
_DIGITS4 = np.array([b"%04d" % k for k in range(10_000)]).view(np.uint32)
"""Four ASCII digits of 0..9999 (zero-padded), one uint32 each: one gather formats a whole column."""
_SIGNIFICANT4 = np.array([bytes(4 - len(str(k))) + b"\x01" * len(str(k)) for k in range(10_000)]).view(np.uint32)
"""1 for the characters of 0..9999 printed without leading zeros, 0 for the padding."""
_ONES4 = np.uint32(0x01010101)


def _width(top: int) -> int:
    return 1 if top < 10 else 4 if top < 10_000 else 8


@functools.lru_cache(maxsize=64)
def _template(widths: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, tuple[int, ...]]:
    """Literal characters of a line whose numbers have ``widths`` (num, x int, width, flags, layer, echo,
    offset, valid), their mask, and where each number starts."""
    w_num, w_int, w_ew, w_flags, w_layer, w_echo, w_off, w_valid = widths
    parts: list[bytes | int] = [w_num, b"; "]
    for sep in (b",", b",", b"; "):
        parts += [b"-", w_int, b".", 8, sep]
    parts += [w_ew, b".", 2, b"; ", w_flags, b"; ", w_layer, b"; ", w_echo, b"; ", b"-", w_off, b"; ", w_valid,
              b"; 0\n"]
    chars, mask, starts = bytearray(), bytearray(), []
    for part in parts:
        if isinstance(part, int):
            starts.append(len(chars))
            chars += b"0" * part
            mask += b"\x00" * part
        else:
            if part == b"-":
                starts.append(len(chars))
            chars += part
            mask += b"\x00" if part == b"-" else b"\x01" * len(part)
    return np.frombuffer(bytes(chars), np.uint8), np.frombuffer(bytes(mask), np.uint8), tuple(starts)


def _scaled_1e8(v: np.ndarray) -> np.ndarray:
    """round(|v|·1e8) exactly as ``%.8f`` rounds (the sign is handled apart)."""
    scaled = np.abs(v) * 1e8
    out = np.rint(scaled).astype(np.int64)
    frac = scaled - np.floor(scaled)
    for idx in np.argwhere(np.abs(frac - 0.5) < 1e-4):
        i = tuple(idx)
        out[i] = int(f"{abs(float(v[i])):.8f}".replace(".", ""))
    return out


def format_points(xyz: np.ndarray, width_cm: np.ndarray, flags: np.ndarray, layer: np.ndarray,
                  echo: np.ndarray, offset_us: np.ndarray) -> bytes:
    """The point lines of one scan (numbered from 1), byte-identical to ``POINT_FMT`` applied row by row."""
    n = len(xyz)
    if n == 0:
        return b""
    width, flag, lay, ech = (np.asarray(c, dtype=np.int64) for c in (width_cm, flags, layer, echo))
    offset = np.asarray(offset_us, dtype=np.int64)
    abs_offset = np.abs(offset)
    if not np.all(np.abs(xyz) < 1e7):
        return _format_points_slow(xyz, width_cm, flags, layer, echo, offset_us)
    scaled = _scaled_1e8(xyz)
    ints, fracs = scaled // 100_000_000, scaled % 100_000_000
    naturals = [np.arange(1, n + 1, dtype=np.int64), ints, width // 100, flag, lay, ech, abs_offset,
                (flag == 0).astype(np.int64)]
    tops = [int(v.max()) for v in naturals]
    if min(int(v.min()) for v in naturals) < 0 or max(tops) >= _LIMIT:
        return _format_points_slow(xyz, width_cm, flags, layer, echo, offset_us)
    widths = tuple(_width(t) for t in tops)
    row_chars, row_mask, starts = _template(widths)
    dest, fixed, hi_of, low_of = _layout(widths, starts, len(row_chars))
    columns = (naturals[0], ints[:, 0], fracs[:, 0], ints[:, 1], fracs[:, 1], ints[:, 2], fracs[:, 2],
               naturals[2], width % 100, flag, lay, ech, abs_offset, naturals[7])
    groups = np.empty((n, len(dest) // 4), dtype=np.int64)
    k = 0
    for col, w in zip(columns, _FIELD_WIDTHS(widths), strict=True):
        if w == 8:
            groups[:, k] = col // 10_000
            groups[:, k + 1] = col % 10_000
            k += 2
        else:
            groups[:, k] = col
            k += 1
    shown = _SIGNIFICANT4[groups]
    shown[:, fixed] = _ONES4
    if len(hi_of):  # 8-digit naturals: the high group only when not 0, the low one then in full
        big = groups[:, hi_of] > 0
        shown[:, low_of] = np.where(big, _ONES4, shown[:, low_of])
        shown[:, hi_of] = np.where(big, shown[:, hi_of], 0)
    chars = np.empty((n, len(row_chars) + 1), dtype=np.uint8)  # the last column takes unused digits
    mask = np.empty((n, len(row_chars) + 1), dtype=np.uint8)
    chars[:, :-1] = row_chars
    mask[:, :-1] = row_mask
    chars[:, dest] = _DIGITS4[groups].view(np.uint8).reshape(n, -1)
    mask[:, dest] = shown.view(np.uint8).reshape(n, -1)
    mask[:, -1] = 0
    sign_cols = [starts[1], starts[4], starts[7], starts[15]]
    mask[:, sign_cols[:3]] = np.signbit(xyz)
    mask[:, sign_cols[3]] = offset < 0
    return np.compress(mask.ravel().view(bool), chars.ravel()).tobytes()  # compress: ~3x a boolean index


def _FIELD_WIDTHS(widths: tuple[int, ...]) -> tuple[int, ...]:  # noqa: N802
    """Digit widths of the 14 numbers of a line, in line order."""
    w_num, w_int, w_ew, w_flags, w_layer, w_echo, w_off, w_valid = widths
    return (w_num, w_int, 8, w_int, 8, w_int, 8, w_ew, 2, w_flags, w_layer, w_echo, w_off, w_valid)


_FIXED_FIELDS = frozenset({2, 4, 6, 8})  # the fractions: printed with their leading zeros


@functools.lru_cache(maxsize=64)
def _layout(widths: tuple[int, ...], starts: tuple[int, ...], line_width: int
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where the 4 bytes of each 4-digit group go in the line (``line_width`` = a trash column for digits
    beyond a number's width), which groups print leading zeros, and the high/low groups of 8-digit naturals."""
    number_starts = [starts[i] for i in (0, 2, 3, 5, 6, 8, 9, 10, 11, 12, 13, 14, 16, 17)]
    dest: list[int] = []
    fixed: list[int] = []
    hi_of: list[int] = []
    low_of: list[int] = []
    for f, (pos, w) in enumerate(zip(number_starts, _FIELD_WIDTHS(widths), strict=True)):
        if w == 8:
            if f not in _FIXED_FIELDS:
                hi_of.append(len(fixed))
                low_of.append(len(fixed) + 1)
            fixed += [f in _FIXED_FIELDS] * 2
            dest += list(range(pos, pos + 8))
        else:
            fixed.append(f in _FIXED_FIELDS)
            dest += [line_width] * (4 - w) + list(range(pos, pos + w))
    return (np.array(dest), np.nonzero(np.array(fixed))[0], np.array(hi_of, dtype=np.int64),
            np.array(low_of, dtype=np.int64))


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
