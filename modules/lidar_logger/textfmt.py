"""The text log's point lines, formatted in numpy instead of one ``%`` conversion per number.

Every line ``num; x,y,z; width; flags; layer; echo; offset; valid; 0`` is a row of 4-byte *cells* (digit
groups, separators with an optional sign, and where they fit a digit group and its separator together: "12.",
"; 3", "45; "). All numbers become integers (x, y, z as round(v·1e8) split into
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


def _scaled_1e8(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """round(|v|·1e8) exactly as ``%.8f`` rounds (``a`` is |v|; the sign is handled apart)."""
    scaled = a * 1e8
    out = np.rint(scaled).astype(np.int64)
    near = np.abs(scaled - np.floor(scaled) - 0.5) < 1e-4
    if near.any():
        for i in zip(*np.nonzero(near), strict=True):
            out[i] = int(f"{abs(float(v[i])):.8f}".replace(".", ""))
    return out


def _cell(text: bytes) -> tuple[np.uint32, np.uint32]:
    """A literal of up to 4 characters as a cell: its bytes (NUL padded) and its mask."""
    chars = np.frombuffer(text.ljust(4, b"\0"), np.uint32)[0]
    mask = np.frombuffer(bytes(1 if i < len(text) else 0 for i in range(4)), np.uint32)[0]
    return chars, mask


def _table(texts: list[bytes], shown: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """Cells of many literals at once: ``texts[k]`` (NUL padded to 4) with ``shown[k]`` as its mask bytes."""
    chars = np.frombuffer(b"".join(t.ljust(4, b"\0") for t in texts), np.uint32)
    masks = np.frombuffer(b"".join(m.ljust(4, b"\0") for m in shown), np.uint32)
    return chars, masks


def _digits_shown(k: int, width: int) -> bytes:
    """Mask bytes of ``k`` printed in ``width`` zero-padded digits without its leading zeros ("0" shows one)."""
    return bytes(width - len(str(k))) + b"\x01" * len(str(k))


_DIGITS2_SEMI, _ = _table([b"%02d; " % k for k in range(100)], [b"\x01" * 4] * 100)
"""The echo width's two centimetre digits and the "; " that follows them."""
_INT_DOT, _INT_DOT_SHOW = _table([b"%03d." % k for k in range(1000)],
                                 [_digits_shown(k, 3) + b"\x01" for k in range(1000)])
"""0..999 without leading zeros and the decimal point after it: the integer part of a metre value."""
_SEMI_SMALL, _SEMI_SMALL_SHOW = _table([b"; %02d" % k for k in range(100)],
                                       [b"\x01\x01" + _digits_shown(k, 2) for k in range(100)])
""""; " and 0..99: a small field (layer, echo, most flags) with its separator in one cell."""
_VALID, _VALID_SHOW = _table([b"; 0", b"; 1"], [b"\x01" * 3] * 2)
_SEMI, _SEMI_SHOW = _cell(b"; ")
_SEMI_MINUS, _ = _cell(b"; -")
_COMMA_SHOW = _cell(b",")[1]
_COMMA_MINUS, _ = _cell(b",-")
_DOT, _DOT_SHOW = _cell(b".")
_END, _END_SHOW = _cell(b"; 0\n")
_SEMI_SIGN = np.uint32(0x010000)  # the '-' of "; -"
_COMMA_SIGN = np.uint32(0x0100)  # the '-' of ",-"
_ZERO = np.uint32(0)


def _bounded(v: np.ndarray, limit: int) -> bool:
    """All of ``v`` in [0, limit): from its dtype alone when that settles it, else from its extremes."""
    if v.dtype.kind == "u" and np.iinfo(v.dtype).max < limit:
        return True
    return len(v) == 0 or (int(v.min()) >= 0 and int(v.max()) < limit)


def format_points(xyz: np.ndarray, width_cm: np.ndarray, flags: np.ndarray, layer: np.ndarray,
                  echo: np.ndarray, offset_us: np.ndarray) -> bytes:
    """The point lines of one scan (numbered from 1), byte-identical to ``POINT_FMT`` applied row by row.

    Each line is a row of 4-byte *cells* (a digit group, a separator, or both when they fit in 4 characters),
    each with a 4-byte mask of the characters printed; the cells are filled a column at a time (one table gather
    per cell) and ``np.compress`` keeps the masked characters, one pass for the whole scan. Fewer, fuller cells
    mean fewer bytes for that pass: it is the formatter's largest single cost.
    """
    n = len(xyz)
    if n == 0:
        return b""
    xyz = np.asarray(xyz, dtype=np.float64)
    width, flag, lay, ech, offset = (np.asarray(c) for c in (width_cm, flags, layer, echo, offset_us))
    a = np.abs(xyz)
    if not (a.max() < 1e7 and _bounded(width, _LIMIT) and _bounded(flag, _LIMIT) and _bounded(lay, _LIMIT)
            and _bounded(ech, _LIMIT) and n < _LIMIT):
        return _format_points_slow(xyz, width_cm, flags, layer, echo, offset_us)
    offset = offset.astype(np.int64, copy=False)
    abs_offset = np.abs(offset)
    if int(abs_offset.max()) >= _LIMIT:
        return _format_points_slow(xyz, width_cm, flags, layer, echo, offset_us)
    ints, fracs = np.divmod(_scaled_1e8(a, xyz), 100_000_000)
    frac_hi, frac_lo = np.divmod(fracs, 10_000)
    negative = np.signbit(xyz)  # -0.0 prints its sign, as Python does
    small_ints = (ints.max(axis=0) < 1000).tolist()
    cells: list[tuple[np.ndarray | np.uint32, np.ndarray | np.uint32]] = []

    def natural(v: np.ndarray, top: int) -> None:  # no leading zeros; 0 prints as "0"; top > every value
        if top <= 10_000:
            cells.append((_DIGITS4[v], _SIGNIFICANT4[v]))
        else:
            hi, lo = np.divmod(v, 10_000)
            big = hi > 0
            cells.append((_DIGITS4[hi], np.where(big, _SIGNIFICANT4[hi], _ZERO)))
            cells.append((_DIGITS4[lo], np.where(big, _ONES4, _SIGNIFICANT4[lo])))

    def small(v: np.ndarray) -> None:  # "; " and a natural, one cell when it is below 100
        if int(v.max()) < 100:
            cells.append((_SEMI_SMALL[v], _SEMI_SMALL_SHOW[v]))
        else:
            cells.append((_SEMI, _SEMI_SHOW))
            natural(v.astype(np.int64, copy=False), int(v.max()) + 1)

    natural(np.arange(1, n + 1, dtype=np.int64), n + 1)
    for k, (sep, show, sign) in enumerate(((_SEMI_MINUS, _SEMI_SHOW, _SEMI_SIGN),
                                           (_COMMA_MINUS, _COMMA_SHOW, _COMMA_SIGN),
                                           (_COMMA_MINUS, _COMMA_SHOW, _COMMA_SIGN))):
        cells.append((sep, show | sign * negative[:, k]))
        if small_ints[k]:
            cells.append((_INT_DOT[ints[:, k]], _INT_DOT_SHOW[ints[:, k]]))
        else:
            natural(ints[:, k], _LIMIT)
            cells.append((_DOT, _DOT_SHOW))
        cells.append((_DIGITS4[frac_hi[:, k]], _ONES4))
        cells.append((_DIGITS4[frac_lo[:, k]], _ONES4))
    metres, cm = np.divmod(width.astype(np.int64, copy=False), 100)
    cells.append((_SEMI, _SEMI_SHOW))
    if int(metres.max()) < 1000:
        cells.append((_INT_DOT[metres], _INT_DOT_SHOW[metres]))
    else:
        natural(metres, _LIMIT)
        cells.append((_DOT, _DOT_SHOW))
    cells.append((_DIGITS2_SEMI[cm], _ONES4))
    natural(flag.astype(np.int64, copy=False), int(flag.max()) + 1)
    small(lay)
    small(ech)
    cells.append((_SEMI_MINUS, _SEMI_SHOW | _SEMI_SIGN * (offset < 0)))
    natural(abs_offset, int(abs_offset.max()) + 1)
    valid = (flag == 0).view(np.uint8)
    cells.append((_VALID[valid], _VALID_SHOW[valid]))
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
