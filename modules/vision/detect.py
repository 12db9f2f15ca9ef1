"""Target detection: a per-pixel colour/brightness score, a threshold, connected components, best blob.

Score (int16):
- grey frames: the pixel value (brightness);
- RGB frames: for a target colour, its "on" channels (component >= 128) and "off" channels: the score is
  min(on channels) - max(off channels), i.e. how strongly the pixel has the target's hue; with no off
  channel (a white target) it is min(R, G, B), i.e. brightness in every channel.

Confidence of a blob, in [0, 1] = area term x contrast term:
- area term = 1 - exp(-area / area_scale): small specks count little, a disc of area >> area_scale ~ 1;
- contrast term = clip((mean score in blob - background score) / contrast_scale, 0, 1), where the
  background score is the median score of the frame (sampled every 8th pixel in each direction).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .labelling import label_runs
from .scene import RGB


def score_map(image: np.ndarray, target_rgb: RGB) -> NDArray[np.int16]:
    """Per-pixel target score (see module docstring) for a uint8 grey or RGB image."""
    if image.ndim == 2:
        return image.astype(np.int16)
    on = [c for c in range(3) if target_rgb[c] >= 128]
    off = [c for c in range(3) if target_rgb[c] < 128]
    if not on:
        raise ValueError(f"target colour {target_rgb} has no bright channel; dark targets are not supported")
    score = image[..., on[0]].astype(np.int16)
    for c in on[1:]:
        np.minimum(score, image[..., c], out=score)
    if off:
        worst = image[..., off[0]].astype(np.int16)
        for c in off[1:]:
            np.maximum(worst, image[..., c], out=worst)
        score -= worst
    return score


@dataclass(frozen=True)
class DetectorConfig:
    """Thresholds of the detector. ``threshold`` is on the score; areas are in pixels."""

    target_rgb: RGB = (255, 0, 0)
    threshold: int = 90
    min_area: int = 12
    max_area_fraction: float = 0.25
    area_scale: float = 40.0
    contrast_scale: float = 100.0
    connectivity: int = 8

    def __post_init__(self) -> None:
        if not all(0 <= c <= 255 for c in self.target_rgb) or len(self.target_rgb) != 3:
            raise ValueError(f"target_rgb {self.target_rgb} must be three values in [0, 255]")
        if not -255 <= self.threshold <= 255:
            raise ValueError(f"threshold {self.threshold} outside [-255, 255]")
        if self.min_area < 1:
            raise ValueError(f"min_area {self.min_area} must be >= 1")
        if not 0.0 < self.max_area_fraction <= 1.0:
            raise ValueError(f"max_area_fraction {self.max_area_fraction} outside (0, 1]")
        if not (self.area_scale > 0.0 and self.contrast_scale > 0.0):
            raise ValueError("area_scale and contrast_scale must be > 0")
        if self.connectivity not in (4, 8):
            raise ValueError(f"connectivity {self.connectivity} must be 4 or 8")


@dataclass(frozen=True, slots=True)
class Blob:
    """A connected component: centroid (x = column, y = row; pixel centres are integers), area in pixels,
    bounding box (inclusive), mean score and confidence."""

    x: float
    y: float
    area: int
    bbox: tuple[int, int, int, int]
    mean_score: float
    confidence: float


@dataclass(frozen=True, slots=True)
class Detection:
    """The best blob of a frame plus how many blobs passed the area limits."""

    blob: Blob
    candidates: int

    @property
    def x(self) -> float:
        return self.blob.x

    @property
    def y(self) -> float:
        return self.blob.y

    @property
    def confidence(self) -> float:
        return self.blob.confidence


def _background_score(score: NDArray[np.int16]) -> float:
    return float(np.median(score[::8, ::8]))


def _ranked_blobs(image: np.ndarray, config: DetectorConfig, limit: int | None) -> tuple[list[Blob], int]:
    """Up to ``limit`` blobs within the area limits, best confidence first, and how many there were."""
    score = score_map(image, config.target_rgb)
    mask = score >= config.threshold
    runs = label_runs(mask, config.connectivity)
    if runs.count == 0:
        return [], 0
    lab, n = runs.label, runs.count
    length = runs.length.astype(np.float64)
    area = np.bincount(lab, weights=length, minlength=n)
    sum_x = np.bincount(lab, weights=length * (runs.start + runs.end - 1) / 2.0, minlength=n)
    sum_y = np.bincount(lab, weights=length * runs.row, minlength=n)
    run_offsets = np.concatenate(([0], np.cumsum(runs.length)[:-1]))
    run_score = np.add.reduceat(score[mask].astype(np.float64), run_offsets)
    sum_score = np.bincount(lab, weights=run_score, minlength=n)
    x0 = np.full(n, np.iinfo(np.int64).max)
    y0 = x0.copy()
    x1 = np.full(n, -1)
    y1 = x1.copy()
    np.minimum.at(x0, lab, runs.start)
    np.minimum.at(y0, lab, runs.row)
    np.maximum.at(x1, lab, runs.end - 1)
    np.maximum.at(y1, lab, runs.row)

    max_area = config.max_area_fraction * mask.size
    keep = np.flatnonzero((area >= config.min_area) & (area <= max_area))
    if keep.size == 0:
        return [], 0
    background = _background_score(score)
    mean_score = sum_score[keep] / area[keep]
    area_term = 1.0 - np.exp(-area[keep] / config.area_scale)
    contrast_term = np.clip((mean_score - background) / config.contrast_scale, 0.0, 1.0)
    confidence = area_term * contrast_term
    order = np.lexsort((-area[keep], -confidence))[:limit]
    blobs = [
        Blob(
            x=float(sum_x[k] / area[k]),
            y=float(sum_y[k] / area[k]),
            area=int(area[k]),
            bbox=(int(x0[k]), int(y0[k]), int(x1[k]), int(y1[k])),
            mean_score=float(mean_score[i]),
            confidence=float(confidence[i]),
        )
        for i, k in ((i, keep[i]) for i in order)
    ]
    return blobs, int(keep.size)


def find_blobs(image: np.ndarray, config: DetectorConfig) -> list[Blob]:
    """All blobs within the area limits, best confidence first."""
    return _ranked_blobs(image, config, None)[0]


def detect(image: np.ndarray, config: DetectorConfig) -> Detection | None:
    """The most confident blob of ``image``, or None when no blob passes the area limits."""
    blobs, candidates = _ranked_blobs(image, config, 1)
    return Detection(blob=blobs[0], candidates=candidates) if blobs else None
