"""IMU frames: both encodings against hand-written bytes, resynchronisation, bad-frame counting."""

import struct

import pytest

from modules.uquad.imu_protocol import BINARY_SIZE, ImuFrame, ImuParser, encode_ascii, encode_binary

FRAME = ImuFrame(9876, (12, -34, 1000), (-5, 6, 7), (300, -200, 100), 235, 101325)


def test_ascii_bytes_by_hand():
    assert encode_ascii(FRAME) == b"A\t9876\t12\t-34\t1000\t-5\t6\t7\t300\t-200\t100\t235\t101325\tZ\n"


def test_binary_bytes_by_hand():
    raw = encode_binary(FRAME)
    assert len(raw) == BINARY_SIZE == 28
    assert raw[0:1] == b"A" and raw[-1:] == b"Z"
    assert raw[1:3] == (9876).to_bytes(2, "little")
    assert raw[3:5] == (12).to_bytes(2, "little", signed=True)
    assert raw[21:23] == (235).to_bytes(2, "little", signed=True)
    assert raw[23:27] == (101325).to_bytes(4, "little")


@pytest.mark.parametrize("mode,enc", [("ascii", encode_ascii), ("binary", encode_binary)])
def test_byte_by_byte_never_partial(mode, enc):
    parser = ImuParser(mode)
    data = enc(FRAME) * 3
    out = []
    for i in range(len(data)):
        got = parser.feed(data[i:i + 1])
        out += got
        # a frame is delivered exactly when its last byte arrives
        assert len(out) == (i + 1) // len(enc(FRAME))
    assert out == [FRAME] * 3
    assert parser.stats.bad_frames == 0


@pytest.mark.parametrize("mode,enc", [("ascii", encode_ascii), ("binary", encode_binary)])
def test_resync_after_garbage_and_truncation(mode, enc):
    parser = ImuParser(mode)
    good = enc(FRAME)
    data = b"\x00A\xffZZ garbage\n" + good + good[: len(good) // 2] + good + b"AAAA" + good
    frames = parser.feed(data)
    assert frames == [FRAME] * 3
    assert parser.stats.bad_frames >= 2  # the leading garbage and the truncated frame at least
    assert parser.stats.bytes_discarded >= len(good) // 2


def test_binary_false_start_inside_frame_is_not_lost():
    # a frame whose loop time bytes contain 'A' (0x41) and garbage before it starting with 'A'
    frame = FRAME._replace(loop_us=0x4141)
    good = encode_binary(frame)
    parser = ImuParser("binary")
    assert parser.feed(b"A\x01\x02" + good) == [frame]
    assert parser.stats.bad_frames == 1


def test_implausible_values_are_bad_frames():
    bad = struct.pack("<cH9hhIc", b"A", 1, *([0] * 9), 235, 5, b"Z")  # 5 Pa
    parser = ImuParser("binary")
    assert parser.feed(bad + encode_binary(FRAME)) == [FRAME]
    assert parser.stats.bad_frames == 1
    ascii_parser = ImuParser("ascii")
    assert ascii_parser.feed(b"A\t1\t2\tZ\n" + b"A\tx\t" + b"1\t" * 11 + b"Z\n" + encode_ascii(FRAME)) == [FRAME]
    assert ascii_parser.stats.bad_frames == 1  # one run of garbage (two bad lines in a row)


def test_ascii_overlong_line_dropped():
    parser = ImuParser("ascii")
    assert parser.feed(b"x" * 500) == []
    assert parser.stats.bad_frames == 1
    assert parser.feed(encode_ascii(FRAME)) == [FRAME]


def test_unknown_mode_refused():
    with pytest.raises(ValueError, match="ascii"):
        ImuParser("hex")


# Frames written by hand from seed 002 §1.3 (not by the project's encoder): "A", loop time, acc xyz, gyro xyz,
# mag xyz, temperature x10, pressure, "Z", tab-separated, one line.
HAND_LINE = b"A\t9876\t12\t-34\t1000\t-5\t6\t7\t300\t-200\t100\t235\t101325\tZ"


def _byte_by_byte(parser: ImuParser, data: bytes) -> list[ImuFrame]:
    out: list[ImuFrame] = []
    for i in range(len(data)):
        out += parser.feed(data[i:i + 1])
    return out


@pytest.mark.parametrize("junk", [b"x", b"A\t1\t2\t", b"\x00\xff?", b"AAAA"])
def test_ascii_frame_after_long_run_without_newline_found_byte_by_byte(junk):
    """A good line after more than 128 characters without a newline is found whatever the reads' sizes."""
    missed = []
    for n in range(100, 340, 3):
        garbage = (junk * n)[:n]
        for chunk in (1, 7):
            parser = ImuParser("ascii")
            data = garbage + HAND_LINE + b"\n"
            out: list[ImuFrame] = []
            for i in range(0, len(data), chunk):
                out += parser.feed(data[i:i + chunk])
            if out != [FRAME]:
                missed.append((n, chunk))
            elif n > 128 and parser.stats.bad_frames < 1:
                missed.append((n, chunk, "garbage not counted"))
    assert missed == []


def test_ascii_crlf_line_ending():
    """Arduino's println ends a line with CR LF: the frame is delivered, nothing counted as bad."""
    data = (HAND_LINE + b"\r\n") * 3
    parser = ImuParser("ascii")
    assert _byte_by_byte(parser, data) == [FRAME] * 3
    assert parser.stats.bad_frames == 0 and parser.stats.bytes_discarded == 0
    parser = ImuParser("ascii")
    assert parser.feed(b"junk\r\n" + data) == [FRAME] * 3
    assert parser.stats.bad_frames == 1


def test_ascii_lone_cr_is_not_a_line_end():
    """A CR inside the line (not before the LF) is still a malformed frame."""
    parser = ImuParser("ascii")
    assert parser.feed(HAND_LINE.replace(b"\t235", b"\r235") + b"\n" + HAND_LINE + b"\n") == [FRAME]
    assert parser.stats.bad_frames == 1
