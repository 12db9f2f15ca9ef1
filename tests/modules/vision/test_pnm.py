import numpy as np
import pytest

from modules.vision.pnm import PnmError, encode_pnm, parse_pnm


def test_p5_with_comments_and_odd_whitespace():
    raster = bytes(range(6))
    data = b"P5 # a comment\n3\t# width above\n 2\r\n# maxval next\n255\n" + raster
    img = parse_pnm(data)
    assert img.dtype == np.uint8 and img.shape == (2, 3)
    assert img.tolist() == [[0, 1, 2], [3, 4, 5]]


def test_p6_rgb_layout():
    raster = bytes([255, 0, 0, 0, 255, 0, 0, 0, 255, 9, 8, 7])
    img = parse_pnm(b"P6\n2 2\n255\n" + raster)
    assert img.shape == (2, 2, 3)
    assert img[0, 0].tolist() == [255, 0, 0] and img[1, 1].tolist() == [9, 8, 7]


def test_raster_may_start_with_a_whitespace_byte_value():
    img = parse_pnm(b"P5\n2 1\n255\n" + b"\n\x20")
    assert img.tolist() == [[10, 32]]


def test_sixteen_bit_and_small_maxval_are_rescaled():
    img16 = parse_pnm(b"P5\n3 1\n65535\n" + np.array([0, 32768, 65535], dtype=">u2").tobytes())
    assert img16.tolist() == [[0, 128, 255]]
    img15 = parse_pnm(b"P5\n3 1\n15\n" + bytes([0, 7, 15]))
    assert img15.tolist() == [[0, 119, 255]]


@pytest.mark.parametrize(
    ("data", "match"),
    [
        (b"P2\n1 1\n255\n0", "magic"),
        (b"P5", "magic"),
        (b"P51 1 255\n\x00", "magic"),
        (b"P6\n640x480\n255\n", "followed by"),
        (b"P5\n1\n", "height"),
        (b"P5\n0 1\n255\n", "empty"),
        (b"P5\n1 1\n0\n\x00", "maxval"),
        (b"P5\n1 1\n70000\n\x00", "maxval"),
        (b"P5\n1 1\n255", "whitespace"),
        (b"P5\n2 2\n255\n\x00\x01\x02", "truncated"),
        (b"P5\n1 1\n255\n\x00\x00", "after the raster"),
        (b"P5\n2 1\n100\n\x10\xff", "above maxval"),
        (b"P5\n123456789012345 1\n255\n", "digits"),
    ],
)
def test_defects_are_clear_errors(data, match):
    with pytest.raises(PnmError, match=match):
        parse_pnm(data)


@pytest.mark.parametrize("shape", [(4, 5), (4, 5, 3)])
def test_encode_then_parse_round_trip(shape):
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, size=shape, dtype=np.uint8)
    data = encode_pnm(img, comment="frame 7\nfrom the test")
    assert data.startswith(b"P6\n" if len(shape) == 3 else b"P5\n")
    assert b"# frame 7 from the test\n" in data
    np.testing.assert_array_equal(parse_pnm(data), img)


def test_encode_refuses_non_uint8():
    with pytest.raises(ValueError):
        encode_pnm(np.zeros((2, 2), dtype=np.float32))
