"""Optional V4L2 (Linux video device) camera source through the ``linuxpy`` package.

Not a dependency of the project: when ``linuxpy`` is missing, constructing ``V4L2Camera`` raises
``CameraUnavailableError`` saying what to install. Frames are requested as uncompressed YUYV (converted to
RGB here with BT.601 limited-range integer arithmetic), or taken as GREY/RGB24 when the driver insists;
compressed formats (MJPEG) are refused because decoding them would need more than numpy.
"""

from __future__ import annotations

import importlib
import logging
import time
from collections.abc import Callable

import numpy as np

from .source import CameraSource, Frame

log = logging.getLogger(__name__)

INSTALL_HINT = "V4L2 capture needs the optional package 'linuxpy' (pip install linuxpy)"
SUPPORTED_FOURCC = ("YUYV", "GREY", "RGB24")


class CameraUnavailableError(RuntimeError):
    """The camera source cannot be used on this machine (missing library, device or format)."""


def yuyv_to_rgb(yuyv: np.ndarray) -> np.ndarray:
    """Packed YUYV 4:2:2 (uint8 H x 2W: Y0 U Y1 V ...) -> uint8 RGB H x W x 3 (BT.601, limited range)."""
    if yuyv.dtype != np.uint8 or yuyv.ndim != 2 or yuyv.shape[1] % 4:
        raise ValueError(f"YUYV data must be uint8 H x 2W with W even, not {yuyv.dtype} {yuyv.shape}")
    quads = yuyv.reshape(yuyv.shape[0], -1, 4).astype(np.int32)
    c = np.stack((quads[..., 0], quads[..., 2]), axis=-1) - 16  # two luma samples per chroma pair
    d = (quads[..., 1] - 128)[..., None]
    e = (quads[..., 3] - 128)[..., None]
    r = (298 * c + 409 * e + 128) >> 8
    g = (298 * c - 100 * d - 208 * e + 128) >> 8
    b = (298 * c + 516 * d + 128) >> 8
    rgb = np.stack((r, g, b), axis=-1).reshape(yuyv.shape[0], -1, 3)
    return np.clip(rgb, 0, 255).astype(np.uint8)


def decode_raw(data: bytes | memoryview, width: int, height: int, fourcc: str) -> np.ndarray:
    """Turn one raw V4L2 buffer into a uint8 image; rows may carry padding (stride = len // height)."""
    bpp = {"YUYV": 2, "GREY": 1, "RGB24": 3}.get(fourcc)
    if bpp is None:
        raise ValueError(f"pixel format {fourcc} not supported (supported: {', '.join(SUPPORTED_FOURCC)})")
    raw = np.frombuffer(data, dtype=np.uint8)
    stride = raw.size // height if height else 0
    if stride < width * bpp:
        raise ValueError(f"buffer of {raw.size} bytes too short for {width}x{height} {fourcc}")
    rows = raw[: stride * height].reshape(height, stride)[:, : width * bpp]
    if fourcc == "YUYV":
        return yuyv_to_rgb(np.ascontiguousarray(rows))
    if fourcc == "GREY":
        return rows.copy()
    return rows.reshape(height, width, 3).copy()


def _import_linuxpy_video() -> object:
    try:
        return importlib.import_module("linuxpy.video.device")
    except ImportError as exc:
        raise CameraUnavailableError(f"{INSTALL_HINT}: {exc}") from exc


class V4L2Camera(CameraSource):
    """Frames from a V4L2 device (``/dev/videoN`` path or index N) at the requested size.

    The driver may choose another size; the actual one is used. A buffer that cannot be decoded is dropped
    and counted in ``dropped``.
    """

    def __init__(
        self,
        device: str | int = 0,
        *,
        width: int = 640,
        height: int = 480,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__()
        video = _import_linuxpy_video()
        self._clock = clock
        self._seq = 0
        self.dropped = 0
        dev_cls = video.Device  # type: ignore[attr-defined]
        self._device = dev_cls.from_id(device) if isinstance(device, int) else dev_cls(device)
        self._device.open()
        try:
            self._capture = video.VideoCapture(self._device)  # type: ignore[attr-defined]
            self._capture.set_format(width, height, "YUYV")
            fmt = self._capture.get_format()
            self.fourcc = getattr(fmt.pixel_format, "name", str(fmt.pixel_format))
            if self.fourcc not in SUPPORTED_FOURCC:
                raise CameraUnavailableError(
                    f"device {device} delivers {self.fourcc}; supported: {', '.join(SUPPORTED_FOURCC)}"
                )
            self.width, self.height = int(fmt.width), int(fmt.height)
            self._capture.open()
            self._frames = iter(self._capture)
        except BaseException:
            self._device.close()
            raise

    def read(self) -> Frame | None:
        if self._closed:
            return None
        while True:
            buffer = next(self._frames, None)
            if buffer is None:
                return None
            try:
                image = decode_raw(bytes(buffer.data), self.width, self.height, self.fourcc)
            except ValueError as exc:
                self.dropped += 1
                log.warning("dropped V4L2 buffer: %s", exc)
                continue
            frame = Frame(image=image, timestamp=self._clock(), seq=self._seq)
            self._seq += 1
            return frame

    def _release(self) -> None:
        try:
            self._capture.close()
        finally:
            self._device.close()
