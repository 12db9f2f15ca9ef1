"""The text log's point lines, formatted in numpy instead of one ``%`` conversion per number.

Every line ``num; x,y,z; width; flags; layer; echo; offset; valid; 0`` is a row of 4-byte *cells*: digit
groups, separators with an optional sign, and where they fit a number and its separator together ("12.", "; 3",
"45; "). All numbers become integers (x, y, z as round(v·1e8) split into integer and 8-digit fraction, echo
width as cm split into metres and 2 digits), each cell column is one table gather for the whole scan, a cell
shorter than 4 characters is padded with NULs (never printed), and ``bytes.translate`` drops the NULs.
The bytes are exactly what ``POINT_FMT % row`` would give:

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


def _cells(texts: list[bytes]) -> np.ndarray:
    """4-byte cells of literals, NUL padded: a NUL is never printed, so it marks the bytes to leave out."""
    return np.frombuffer(b"".join(t.ljust(4, b"\0") for t in texts), np.uint32)


_DIGITS4 = np.frombuffer(b"".join(b"%04d" % k for k in range(10_000)), np.uint32)
"""Four ASCII digits of 0..9999, zero-padded: the low group of a wide number, and the 8 decimals."""
_NATURAL4 = _cells([b"%d" % k for k in range(10_000)])
"""0..9999 as ``%d`` prints it (no leading zeros; 0 prints "0")."""
_INT_DOT = _cells([b"%d." % k for k in range(1000)])
"""0..999 and the decimal point after it: the integer part of a metre value."""
_SEMI_SMALL = _cells([b"; %d" % k for k in range(100)])
""""; " and 0..99: a small field (layer, echo) with its separator in one cell."""
_DIGITS2_SEMI = _cells([b"%02d; " % k for k in range(100)])
"""The echo width's two centimetre digits and the "; " that follows them."""
_VALID = _cells([b"; 0", b"; 1"])
(_SEMI, _SEMI_MINUS, _COMMA, _COMMA_MINUS, _DOT, _END) = _cells([b"; ", b"; -", b",", b",-", b".", b"; 0\n"])
_ZERO = np.uint32(0)
_SEPS = np.array([_SEMI, _COMMA, _COMMA])
_SIGNED_SEPS = np.array([_SEMI_MINUS, _COMMA_MINUS, _COMMA_MINUS])
"""What comes before x, y and z: "; " "," ",", or with a minus sign."""


def _scaled_1e8(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """round(|v|·1e8) exactly as ``%.8f`` rounds (``a`` is |v|; the sign is handled apart)."""
    scaled = a * 1e8
    rounded = np.rint(scaled)
    out = rounded.astype(np.int64)
    near = np.abs(scaled - rounded) > 0.5 - 1e-4  # a fraction within 1e-4 of a half
    if near.any():
        for i in zip(*np.nonzero(near), strict=True):
            out[i] = int(f"{abs(float(v[i])):.8f}".replace(".", ""))
    return out


def _bounded(v: np.ndarray, limit: int) -> bool:
    """All of ``v`` in [0, limit): from its dtype alone when that settles it, else from its extremes."""
    if v.dtype.kind == "u" and np.iinfo(v.dtype).max < limit:
        return True
    return len(v) == 0 or (int(v.min()) >= 0 and int(v.max()) < limit)


def format_points(xyz: np.ndarray, width_cm: np.ndarray, flags: np.ndarray, layer: np.ndarray,
                  echo: np.ndarray, offset_us: np.ndarray) -> bytes:
    """The point lines of one scan (numbered from 1), byte-identical to ``POINT_FMT`` applied row by row.

    Each line is a row of 4-byte *cells* (a digit group, a separator, or both when they fit in 4 characters),
    NUL where a cell has fewer characters; the cells are filled a column at a time (one table gather per cell)
    and one ``translate`` drops the NULs of the whole scan. Fewer, fuller cells mean fewer bytes for that pass:
    it is the formatter's largest single cost.
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
    cells: list[np.ndarray | np.uint32] = []

    def natural(v: np.ndarray, top: int) -> None:  # as %d prints it; top > every value
        if top <= 10_000:
            cells.append(_NATURAL4[v])
        else:
            hi, lo = np.divmod(v, 10_000)
            big = hi > 0
            cells.append(np.where(big, _NATURAL4[hi], _ZERO))
            cells.append(np.where(big, _DIGITS4[lo], _NATURAL4[lo]))

    def small(v: np.ndarray) -> None:  # "; " and a natural, one cell when it is below 100
        top = int(v.max())
        if top < 100:
            cells.append(_SEMI_SMALL[v])
        else:
            cells.append(_SEMI)
            natural(v.astype(np.int64, copy=False), top + 1)

    natural(np.arange(1, n + 1, dtype=np.int64), n + 1)
    if all(small_ints):  # the usual case (|x|, |y|, |z| < 1000 m): the 12 cells of x, y, z as one block
        xyz_cells = np.empty((n, 3, 4), dtype=np.uint32)
        xyz_cells[:, :, 0] = np.where(negative, _SIGNED_SEPS, _SEPS)
        xyz_cells[:, :, 1] = _INT_DOT[ints]
        xyz_cells[:, :, 2] = _DIGITS4[frac_hi]
        xyz_cells[:, :, 3] = _DIGITS4[frac_lo]
        cells.append(xyz_cells.reshape(n, 12))
    else:
        for k, (plain, minus) in enumerate(((_SEMI, _SEMI_MINUS), (_COMMA, _COMMA_MINUS), (_COMMA, _COMMA_MINUS))):
            cells.append(np.where(negative[:, k], minus, plain))
            if small_ints[k]:
                cells.append(_INT_DOT[ints[:, k]])
            else:
                natural(ints[:, k], _LIMIT)
                cells.append(_DOT)
            cells.append(_DIGITS4[frac_hi[:, k]])
            cells.append(_DIGITS4[frac_lo[:, k]])
    metres, cm = np.divmod(width.astype(np.int64, copy=False), 100)
    cells.append(_SEMI)
    if int(metres.max()) < 1000:
        cells.append(_INT_DOT[metres])
    else:
        natural(metres, _LIMIT)
        cells.append(_DOT)
    cells.append(_DIGITS2_SEMI[cm])
    natural(flag.astype(np.int64, copy=False), int(flag.max()) + 1)
    small(lay)
    small(ech)
    cells.append(np.where(offset < 0, _SEMI_MINUS, _SEMI))
    natural(abs_offset, int(abs_offset.max()) + 1)
    cells.append(_VALID[(flag == 0).view(np.uint8)])
    cells.append(_END)
    width_cells = [c.shape[1] if isinstance(c, np.ndarray) and c.ndim == 2 else 1 for c in cells]
    chars = np.empty((n, sum(width_cells)), dtype=np.uint32)
    j = 0
    for c, w in zip(cells, width_cells, strict=True):
        if w == 1:
            chars[:, j] = c
        else:
            chars[:, j:j + w] = c
        j += w
    return chars.tobytes().translate(None, b"\0")  # drops the NULs: faster than np.compress over a mask


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
