"""Camera source replaying a folder of PGM/PPM/NPY images in name order, at a given rate, optionally looping.

A file that cannot be decoded is dropped, counted and logged; reading continues with the next file.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .pnm import parse_pnm
from .source import CameraSource, Frame, check_image

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".pgm", ".ppm", ".pnm", ".npy")


def load_image(path: Path) -> np.ndarray:
    """Read one image file (by suffix); raise ValueError/OSError/EOFError saying why it is not usable."""
    suffix = path.suffix.lower()
    if suffix == ".npy":
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.ndarray):  # a zip (.npz) archive renamed .npy
            loaded.close()
            raise ValueError("not a single .npy array")
        image = loaded
        if image.ndim == 3 and image.shape[2] == 1:
            image = image[:, :, 0]
        check_image(image)
        return image
    if suffix in (".pgm", ".ppm", ".pnm"):
        return parse_pnm(path.read_bytes())
    raise ValueError(f"unsupported image suffix {suffix!r}")


def list_images(folder: Path) -> list[Path]:
    """Image files of ``folder`` (not recursive) sorted by file name."""
    return sorted(
        (p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES), key=lambda p: p.name
    )


class FolderCamera(CameraSource):
    """Frames from the image files of a folder.

    ``rate_hz`` paces ``read()``: frame k is not returned before ``t0 + k / rate_hz`` (t0 = first read),
    waiting with ``sleep``; None means as fast as called. Timestamps come from ``clock`` when the frame is
    returned. With ``loop`` the sequence restarts after the last file; otherwise ``read()`` returns None.
    Undecodable files are skipped: ``dropped`` counts them and ``last_error`` names the latest.
    """

    def __init__(
        self,
        folder: str | Path,
        *,
        rate_hz: float | None = None,
        loop: bool = False,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        super().__init__()
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise FileNotFoundError(f"camera folder {self.folder} does not exist or is not a directory")
        if rate_hz is not None and not rate_hz > 0.0:
            raise ValueError(f"rate_hz {rate_hz!r} must be > 0")
        self.files = list_images(self.folder)
        if not self.files:
            raise ValueError(f"camera folder {self.folder} holds no {'/'.join(IMAGE_SUFFIXES)} files")
        self.rate_hz = rate_hz
        self.loop = loop
        self.dropped = 0
        self.last_error: str | None = None
        self._clock = clock
        self._sleep = sleep
        self._index = 0
        self._seq = 0
        self._t0: float | None = None

    def _next_image(self) -> np.ndarray | None:
        """The next decodable image, or None at the end (or after a full pass with nothing decodable)."""
        for _ in range(len(self.files)):
            if self._index >= len(self.files):
                if not self.loop:
                    return None
                self._index = 0
            path = self.files[self._index]
            self._index += 1
            try:
                return load_image(path)
            except (OSError, ValueError, EOFError) as exc:
                self.dropped += 1
                self.last_error = f"{path}: {exc}"
                log.warning("dropped frame file %s", self.last_error)
        return None

    def _wait_turn(self) -> None:
        if self.rate_hz is None:
            return
        now = self._clock()
        if self._t0 is None:
            self._t0 = now
        due = self._t0 + self._seq / self.rate_hz
        if due > now:
            self._sleep(due - now)

    def read(self) -> Frame | None:
        if self._closed:
            return None
        image = self._next_image()
        if image is None:
            return None
        self._wait_turn()
        frame = Frame(image=image, timestamp=self._clock(), seq=self._seq)
        self._seq += 1
        return frame
