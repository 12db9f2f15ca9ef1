"""V4L2 is optional: the raw-buffer decoding is tested here; capture itself needs linuxpy and a device."""

import sys

import numpy as np
import pytest

from modules.vision.v4l2_camera import CameraUnavailableError, V4L2Camera, decode_raw, yuyv_to_rgb


def yuyv(pairs):
    """One row of YUYV bytes from (Y0, U, Y1, V) tuples."""
    return np.array([list(sum(pairs, ()))], dtype=np.uint8)


def test_yuyv_reference_colours_bt601_limited_range():
    rgb = yuyv_to_rgb(yuyv([(235, 128, 16, 128), (81, 90, 81, 240), (145, 54, 145, 34), (41, 240, 41, 110)]))
    assert rgb.shape == (1, 4 * 2, 3)
    assert rgb[0, 0].tolist() == [255, 255, 255]
    assert rgb[0, 1].tolist() == [0, 0, 0]
    red, green, blue = rgb[0, 2], rgb[0, 4], rgb[0, 6]
    assert red[0] >= 250 and red[1] <= 5 and red[2] <= 5
    assert green[1] >= 250 and green[0] <= 5 and green[2] <= 5
    assert blue[2] >= 250 and blue[0] <= 5 and blue[1] <= 5
    np.testing.assert_array_equal(rgb[0, 2], rgb[0, 3])  # both pixels of a pair share chroma


def test_decode_handles_row_padding_and_formats():
    h, w = 2, 4
    grey = np.arange(h * 6, dtype=np.uint8).reshape(h, 6)  # stride 6 > width 4
    np.testing.assert_array_equal(decode_raw(grey.tobytes(), w, h, "GREY"), grey[:, :w])
    rgb = np.arange(h * w * 3, dtype=np.uint8).reshape(h, w, 3)
    np.testing.assert_array_equal(decode_raw(rgb.tobytes(), w, h, "RGB24"), rgb)
    packed = np.tile(np.array([235, 128, 235, 128], np.uint8), (h, w // 2))
    assert decode_raw(packed.tobytes(), w, h, "YUYV").tolist() == [[[255, 255, 255]] * w] * h


def test_decode_rejects_short_buffers_and_unknown_formats():
    with pytest.raises(ValueError, match="too short"):
        decode_raw(b"\x00" * 10, 4, 2, "YUYV")
    with pytest.raises(ValueError, match="not supported"):
        decode_raw(b"\x00" * 100, 4, 2, "MJPG")
    with pytest.raises(ValueError):
        yuyv_to_rgb(np.zeros((2, 6), np.uint8))


def test_missing_linuxpy_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "linuxpy", None)  # makes "import linuxpy..." fail like a missing package
    with pytest.raises(CameraUnavailableError, match="pip install linuxpy"):
        V4L2Camera("/dev/video0")
