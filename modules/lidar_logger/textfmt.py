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


def _digits(v: np.ndarray, width: int, natural: bool) -> tuple[np.ndarray, np.ndarray]:
    """ASCII digits (..., width) of 0 ≤ v < 10**width and which of them are printed."""
    if width == 1:
        return (v + ord("0")).astype(np.uint8)[..., None], np.ones(v.shape + (1,), dtype=np.uint8)
    if width <= 4:
        chars = _DIGITS4[v].view(np.uint8).reshape(v.shape + (4,))[..., 4 - width:]
        shown = (_SIGNIFICANT4[v] if natural else np.full(v.shape, _ONES4)).view(np.uint8)
        return chars, shown.reshape(v.shape + (4,))[..., 4 - width:]
    hi, lo = v // 10_000, v % 10_000
    words = np.empty(v.shape + (2,), dtype=np.uint32)
    words[..., 0] = _DIGITS4[hi]
    words[..., 1] = _DIGITS4[lo]
    shown = np.empty(v.shape + (2,), dtype=np.uint32)
    if natural:
        big = hi > 0
        shown[..., 0] = np.where(big, _SIGNIFICANT4[hi], 0)
        shown[..., 1] = np.where(big, _ONES4, _SIGNIFICANT4[lo])
    else:
        shown[:] = _ONES4
    return words.view(np.uint8).reshape(v.shape + (8,)), shown.view(np.uint8).reshape(v.shape + (8,))


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
    chars = np.empty((n, len(row_chars)), dtype=np.uint8)
    mask = np.empty((n, len(row_chars)), dtype=np.uint8)
    chars[:] = row_chars
    mask[:] = row_mask
    (p_num, p_xsign, p_xint, p_xfrac, p_ysign, p_yint, p_yfrac, p_zsign, p_zint, p_zfrac, p_ew, p_ewfrac,
     p_flags, p_layer, p_echo, p_osign, p_off, p_valid) = starts
    stride = p_ysign - p_xsign

    def put(pos: int, v: np.ndarray, w: int, natural: bool = True) -> None:
        c, m = _digits(v, w, natural)
        chars[:, pos:pos + w] = c
        mask[:, pos:pos + w] = m

    def put3(pos: int, c: np.ndarray, m: np.ndarray) -> None:
        """The same column of x, y and z, which sit ``stride`` apart: one assignment through a strided view."""
        w = c.shape[-1]
        off = pos - p_xsign
        chars[:, p_xsign:p_xsign + 3 * stride].reshape(n, 3, stride)[:, :, off:off + w] = c
        mask[:, p_xsign:p_xsign + 3 * stride].reshape(n, 3, stride)[:, :, off:off + w] = m

    put(p_num, naturals[0], widths[0])
    put3(p_xsign, np.full((n, 3, 1), ord("-"), dtype=np.uint8), np.signbit(xyz).astype(np.uint8)[..., None])
    put3(p_xint, *_digits(ints, widths[1], True))
    put3(p_xfrac, *_digits(fracs, 8, False))
    put(p_ew, naturals[2], widths[2])
    put(p_ewfrac, width % 100, 2, natural=False)
    for pos, k in ((p_flags, 3), (p_layer, 4), (p_echo, 5), (p_off, 6), (p_valid, 7)):
        put(pos, naturals[k], widths[k])
    mask[:, p_osign] = offset < 0
    chars[:, p_osign] = ord("-")
    return chars[mask.view(bool)].tobytes()


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
