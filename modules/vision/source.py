"""The one small interface every camera source implements, and the frame it returns."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from types import TracebackType

import numpy as np


def check_image(image: np.ndarray) -> None:
    """Raise ValueError unless ``image`` is uint8 HxW (grey) or HxWx3 (RGB), non-empty."""
    if not isinstance(image, np.ndarray):
        raise ValueError(f"image must be a numpy array, not {type(image).__name__}")
    if image.dtype != np.uint8:
        raise ValueError(f"image dtype must be uint8, not {image.dtype}")
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise ValueError(f"image shape must be HxW or HxWx3, not {image.shape}")
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"image is empty: {image.shape}")


@dataclass(frozen=True, slots=True)
class Frame:
    """One camera image: uint8 HxW (grey) or HxWx3 (RGB), the source clock time (s) and a sequence number."""

    image: np.ndarray
    timestamp: float
    seq: int

    def __post_init__(self) -> None:
        check_image(self.image)

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def height(self) -> int:
        return int(self.image.shape[0])


class CameraSource(ABC):
    """A source of frames. ``read()`` returns the next frame, or None when none is available
    (end of a folder, no pose yet for the simulator, source closed). ``close()`` may be called any number
    of times; sources are context managers."""

    def __init__(self) -> None:
        self._closed = False

    @abstractmethod
    def read(self) -> Frame | None:
        """Next frame, or None."""

    def _release(self) -> None:  # noqa: B027 - optional hook, most sources hold nothing to release
        """Free resources; called once by ``close()``."""

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        """Release the source; later calls do nothing and ``read()`` returns None."""
        if not self._closed:
            self._closed = True
            self._release()

    def __enter__(self) -> CameraSource:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
