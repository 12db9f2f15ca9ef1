"""Detection on synthetic frames with known target positions.

Stated bound: for a disc of radius >= 5 px drawn at a sub-pixel centre on a textured background with
Gaussian noise sigma = 8 grey levels per channel, the centroid is within 0.5 px of the true centre.
"""

import numpy as np
import pytest

from modules.vision.detect import DetectorConfig, detect, find_blobs, score_map

PIXEL_BOUND = 0.5
H, W = 480, 640


def background(rng, grey=False):
    """Blocky muted texture (8 px cells), green-brown like the simulator's ground."""
    cells = rng.uniform(60, 140, size=(H // 8 + 1, W // 8 + 1))
    base = np.kron(cells, np.ones((8, 8)))[:H, :W].astype(np.float32)
    if grey:
        return base
    return np.stack((base, base * 1.1, base * 0.7), axis=-1)


def draw_disc(img, cx, cy, r, value):
    v, u = np.mgrid[0:H, 0:W]
    img[(u - cx) ** 2 + (v - cy) ** 2 <= r * r] = value
    return img


def finish(img, rng, noise):
    return np.clip(img + rng.normal(0.0, noise, img.shape) + 0.5, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("radius", [5, 6, 9, 15, 30])
def test_disc_centroid_within_bound_with_noise(radius):
    rng = np.random.default_rng(radius)
    for _ in range(15):
        cx, cy = rng.uniform(40, W - 40), rng.uniform(40, H - 40)
        img = finish(draw_disc(background(rng), cx, cy, radius, (255, 20, 20)), rng, noise=8.0)
        det = detect(img, DetectorConfig())
        assert det is not None
        assert np.hypot(det.x - cx, det.y - cy) < PIXEL_BOUND
        assert det.blob.area == pytest.approx(np.pi * radius**2, rel=0.15)
        assert det.candidates == 1
        x0, y0, x1, y1 = det.blob.bbox
        assert x0 <= cx <= x1 and y0 <= cy <= y1


def test_grey_frames_use_brightness():
    rng = np.random.default_rng(3)
    img = finish(draw_disc(background(rng, grey=True), 101.3, 57.8, 7, 250.0), rng, noise=8.0)
    assert img.ndim == 2
    det = detect(img, DetectorConfig(threshold=200))
    assert det is not None
    assert np.hypot(det.x - 101.3, det.y - 57.8) < PIXEL_BOUND


def test_disc_touching_the_image_border_is_found():
    rng = np.random.default_rng(4)
    img = finish(draw_disc(background(rng), 0.0, 300.0, 10, (255, 20, 20)), rng, noise=8.0)
    det = detect(img, DetectorConfig())
    assert det is not None and det.blob.bbox[0] == 0
    assert det.y == pytest.approx(300.0, abs=PIXEL_BOUND)


@pytest.mark.parametrize("seed", range(5))
def test_no_detection_on_target_free_frames(seed):
    rng = np.random.default_rng(seed)
    assert detect(finish(background(rng), rng, noise=8.0), DetectorConfig()) is None
    assert detect(finish(background(rng, grey=True), rng, noise=8.0), DetectorConfig(threshold=200)) is None
    flat = np.zeros((H, W, 3), np.uint8)
    assert detect(flat, DetectorConfig()) is None


def test_target_colour_selects_the_blob():
    rng = np.random.default_rng(5)
    img = background(rng)
    draw_disc(img, 100.0, 100.0, 8, (255, 20, 20))
    draw_disc(img, 400.0, 300.0, 8, (250, 240, 30))
    img = finish(img, rng, noise=4.0)
    red = detect(img, DetectorConfig(target_rgb=(255, 0, 0)))
    yellow = detect(img, DetectorConfig(target_rgb=(255, 255, 0)))
    assert (round(red.x), round(red.y)) == (100, 100)
    assert (round(yellow.x), round(yellow.y)) == (400, 300)


def test_blobs_are_ranked_by_confidence_and_small_specks_ignored():
    rng = np.random.default_rng(6)
    img = background(rng)
    draw_disc(img, 500.0, 100.0, 4, (255, 20, 20))  # area ~49: lower area term
    draw_disc(img, 200.0, 300.0, 12, (255, 20, 20))
    img[10, 10] = (255, 0, 0)  # single pixel below min_area
    blobs = find_blobs(finish(img, rng, noise=2.0), DetectorConfig())
    assert [(round(b.x), round(b.y)) for b in blobs] == [(200, 300), (500, 100)]
    assert blobs[0].confidence > blobs[1].confidence
    assert all(0.0 <= b.confidence <= 1.0 for b in blobs)


def test_confidence_grows_with_area_and_contrast():
    rng = np.random.default_rng(7)
    confidences = []
    for radius, colour in [(3, (255, 20, 20)), (6, (255, 20, 20)), (6, (170, 100, 60))]:
        img = finish(draw_disc(background(rng), 300.0, 200.0, radius, colour), rng, noise=1.0)
        confidences.append(detect(img, DetectorConfig(threshold=60)).confidence)
    small, large, weak = confidences
    assert small < large
    assert weak < large


def test_blob_larger_than_max_area_is_not_a_target():
    img = np.zeros((H, W, 3), np.uint8)
    img[:, :, 0] = 255  # the whole frame is "red"
    assert detect(img, DetectorConfig()) is None
    assert detect(img, DetectorConfig(max_area_fraction=1.0)) is not None


def test_score_map_definitions():
    img = np.array([[[200, 50, 30], [90, 200, 210], [240, 230, 220]]], dtype=np.uint8)
    assert score_map(img, (255, 0, 0)).tolist() == [[150, -120, 10]]
    assert score_map(img, (0, 255, 255)).tolist() == [[-170, 110, -20]]
    assert score_map(img, (255, 255, 255)).tolist() == [[30, 90, 220]]
    assert score_map(img[..., 0], (255, 0, 0)).tolist() == [[200, 90, 240]]
    with pytest.raises(ValueError, match="dark"):
        score_map(img, (0, 0, 0))


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(target_rgb=(300, 0, 0)),
        dict(threshold=400),
        dict(min_area=0),
        dict(max_area_fraction=0.0),
        dict(area_scale=0.0),
        dict(connectivity=6),
    ],
)
def test_bad_detector_config(kwargs):
    with pytest.raises(ValueError):
        DetectorConfig(**kwargs)
