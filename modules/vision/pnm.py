"""Binary PGM (P5) and PPM (P6) images, parsed and written by hand (Netpbm format).

Header: magic, then width, height and maxval as ASCII decimals separated by whitespace, with ``#`` comments
allowed up to the maxval; exactly one whitespace byte, then the raster. maxval < 256 means one byte per
sample, otherwise two bytes big-endian. Samples are rescaled to 0..255 when maxval is not 255.
Only single-image files are accepted: bytes after the raster are an error (a sign of a corrupt file).
"""

from __future__ import annotations

import numpy as np

from .source import check_image

_WHITESPACE = b" \t\n\v\f\r"
_MAX_DIGITS = 10


class PnmError(ValueError):
    """The bytes are not a valid binary PGM/PPM image."""


def _skip_space_and_comments(data: bytes, pos: int) -> int:
    while pos < len(data):
        if data[pos] in _WHITESPACE:
            pos += 1
        elif data[pos] == ord("#"):
            while pos < len(data) and data[pos] not in b"\r\n":
                pos += 1
        else:
            break
    return pos


def _read_number(data: bytes, pos: int, name: str) -> tuple[int, int]:
    pos = _skip_space_and_comments(data, pos)
    start = pos
    while pos < len(data) and 48 <= data[pos] <= 57 and pos - start <= _MAX_DIGITS:
        pos += 1
    if pos == start:
        raise PnmError(f"header: expected {name} (a decimal number) at byte {start}")
    if pos - start > _MAX_DIGITS:
        raise PnmError(f"header: {name} at byte {start} has too many digits")
    if pos < len(data) and data[pos] not in _WHITESPACE and data[pos] != ord("#"):
        raise PnmError(f"header: {name} at byte {start} is followed by {data[pos : pos + 1]!r}")
    return int(data[start:pos]), pos


def parse_pnm(data: bytes) -> np.ndarray:
    """Decode a P5 (-> uint8 HxW) or P6 (-> uint8 HxWx3) image; raise PnmError on any defect."""
    magic = data[:2]
    if magic not in (b"P5", b"P6") or len(data) < 3 or data[2] not in _WHITESPACE:
        raise PnmError(f"not a binary PGM/PPM: magic {data[:3]!r} (expected P5 or P6)")
    width, pos = _read_number(data, 2, "width")
    height, pos = _read_number(data, pos, "height")
    maxval, pos = _read_number(data, pos, "maxval")
    if width < 1 or height < 1:
        raise PnmError(f"header: image size {width}x{height} is empty")
    if not 1 <= maxval <= 65535:
        raise PnmError(f"header: maxval {maxval} outside [1, 65535]")
    if pos >= len(data) or data[pos] not in _WHITESPACE:
        raise PnmError("header: maxval must be followed by one whitespace byte")
    pos += 1
    channels = 3 if magic == b"P6" else 1
    dtype = np.dtype(np.uint8) if maxval < 256 else np.dtype(">u2")
    expected = width * height * channels * dtype.itemsize
    body = len(data) - pos
    if body < expected:
        raise PnmError(f"raster truncated: {body} of {expected} bytes")
    if body > expected:
        raise PnmError(f"{body - expected} unexpected bytes after the raster")
    raster = np.frombuffer(data, dtype=dtype, count=width * height * channels, offset=pos)
    if int(raster.max()) > maxval:
        raise PnmError(f"sample value {int(raster.max())} above maxval {maxval}")
    if maxval != 255:
        raster = ((raster.astype(np.uint32) * 255 + maxval // 2) // maxval).astype(np.uint8)
    shape = (height, width, 3) if channels == 3 else (height, width)
    return raster.reshape(shape).copy()


def encode_pnm(image: np.ndarray, comment: str | None = None) -> bytes:
    """Encode a uint8 HxW image as P5 or HxWx3 as P6 (maxval 255), with an optional header comment."""
    check_image(image)
    magic = b"P6" if image.ndim == 3 else b"P5"
    note = b"" if comment is None else b"# " + comment.replace("\n", " ").encode() + b"\n"
    header = magic + b"\n" + note + f"{image.shape[1]} {image.shape[0]}\n255\n".encode()
    return header + np.ascontiguousarray(image).tobytes()
