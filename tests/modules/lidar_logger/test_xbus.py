"""Xbus framing: exact bytes, normal and extended length, checksum failures, resynchronisation."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from modules.lidar_logger.xbus import MID, Frame, FrameParser, build_frame


def test_known_frames_match_the_reference_bytes() -> None:
    assert build_frame(MID.GOTO_CONFIG) == bytes.fromhex("FAFF3000D1")
    assert build_frame(MID.GOTO_MEASUREMENT) == bytes.fromhex("FAFF1000F1")
    assert build_frame(MID.REQ_DATA) == bytes.fromhex("FAFF3400CD")
    assert build_frame(MID.SET_OUTPUT_MODE, bytes.fromhex("0834")) == bytes.fromhex("FAFFD0020834F3")
    assert build_frame(MID.SET_OUTPUT_SETTINGS, bytes.fromhex("00000005")) == bytes.fromhex(
        "FAFFD2040000000526"
    )


def test_length_254_is_normal_and_255_is_extended() -> None:
    short = build_frame(0x32, bytes(254))
    assert short[3] == 254 and len(short) == 4 + 254 + 1
    ext = build_frame(0x32, bytes(range(255)))
    assert ext[3] == 0xFF and ext[4:6] == (255).to_bytes(2, "big") and len(ext) == 6 + 255 + 1
    assert sum(ext[1:]) & 0xFF == 0


def test_extended_frames_parse_back_for_lengths_with_any_high_byte() -> None:
    parser = FrameParser()
    payloads = [bytes((i * 7) & 0xFF for i in range(n)) for n in (255, 256, 511, 1000, 4097, 8192)]
    stream = b"".join(build_frame(0x32, p) for p in payloads)
    frames = parser.feed(stream)
    assert [f.data for f in frames] == payloads
    assert parser.bad_checksum == 0 and parser.discarded_bytes == 0


def test_bad_checksum_is_dropped_and_counted_and_the_next_frame_survives() -> None:
    good1 = build_frame(MID.GOTO_CONFIG + 1)
    bad = bytearray(build_frame(0x32, b"\x01\x02\x03"))
    bad[5] ^= 0x40
    good2 = build_frame(0x32, b"\x09\x08")
    parser = FrameParser()
    frames = parser.feed(good1 + bytes(bad) + good2)
    assert frames == [Frame(0x31, b""), Frame(0x32, b"\x09\x08")]
    assert parser.bad_checksum == 1
    assert parser.discarded_bytes == len(bad)


def test_bad_extended_checksum_is_dropped() -> None:
    bad = bytearray(build_frame(0x32, bytes(300)))
    bad[-1] ^= 1
    parser = FrameParser()
    assert parser.feed(bytes(bad) + build_frame(0x11)) == [Frame(0x11, b"")]
    assert parser.bad_checksum == 1


def test_impossible_extended_length_costs_one_byte() -> None:
    parser = FrameParser(max_data=1000)
    junk = bytes.fromhex("FAFF32FF2000")  # claims 8192 bytes
    frames = parser.feed(junk + build_frame(0x35))
    assert frames == [Frame(0x35, b"")]
    assert parser.bad_length == 1


def test_garbage_before_a_frame_is_skipped_and_counted() -> None:
    parser = FrameParser()
    frames = parser.feed(b"\x00\x13\x37hello" + build_frame(0x0B, b"\x00\x43"))
    assert frames == [Frame(0x0B, b"\x00\x43")]
    assert parser.discarded_bytes == 8


def test_frame_split_at_every_byte_boundary() -> None:
    wire = build_frame(0x32, bytes(range(40))) + build_frame(0x32, bytes(300))
    for cut in range(1, len(wire)):
        parser = FrameParser()
        frames = parser.feed(wire[:cut]) + parser.feed(wire[cut:])
        assert [len(f.data) for f in frames] == [40, 300], cut
        assert parser.pending == 0


@settings(max_examples=150, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.integers(0, 255),
            st.binary(max_size=600),
            st.binary(max_size=30).map(lambda b: b.replace(b"\xfa", b"\x00")),
        ),
        max_size=8,
    ),
    st.integers(1, 64),
)
def test_frames_between_garbage_without_preambles_are_all_recovered(items, chunk) -> None:
    stream = b"".join(junk + build_frame(mid, data) for mid, data, junk in items)
    parser = FrameParser()
    out = []
    for i in range(0, len(stream), chunk):
        out += parser.feed(stream[i : i + chunk])
    assert [(f.mid, f.data) for f in out] == [(mid, data) for mid, data, _ in items]
    assert parser.bad_checksum == 0


def test_hand_written_mtdata_with_a_bad_checksum_then_a_good_one() -> None:
    """Frames written by hand from the Xbus description (FA, BID FF, MID 32, LEN, data, CS with the sum of
    BID..CS ≡ 0 mod 256), not by build_frame: the corrupt one is counted as damaged, the good one after it found."""
    data = bytes(range(1, 11))
    cs = (-(0xFF + 0x32 + 10 + sum(data))) & 0xFF
    good = bytes((0xFA, 0xFF, 0x32, 10)) + data + bytes((cs,))
    bad = bytes((0xFA, 0xFF, 0x32, 10)) + data + bytes(((cs + 1) & 0xFF,))
    parser = FrameParser()
    frames = [f for b in bad + bad + good for f in parser.feed(bytes((b,)))]
    assert frames == [Frame(0x32, data)]
    assert parser.bad_checksum == 2 and parser.damaged == 2
